#!/usr/bin/env bash
# The regression gate of this package's repository, for CI (.github/workflows/tissuebench-gate.yml)
# or by hand:  bash ci/gate.sh [BASE]
#
# 1. sweeps the package's spec with this checkout's code (tissuebench sweep);
# 2. `tissuebench check --against` the merge base of HEAD and BASE: REF's code (the package at the
#    merge base, exported from git; the same tissuebench) runs the same sweep, every unit's error
#    must equal REF's, and every unit is timed A/B (both versions, in turn, on one core);
# 3. writes JUnit ($OUT/_junit.xml: the results store reads no file named _*); the A/B's samples,
#    verdicts and plot are in $OUT/_gate/.
#
# An intended change of an error: record it in the baseline file ($BASELINE, committed in this
# repository) in the change's branch. After a gate that failed on it, run the command it prints:
#     tissuebench check out/tissuebench-gate --baseline ci/baseline.toml --update-baseline
# and commit ci/baseline.toml with the change; the check then notes the units whose entry the
# branch edits as declared changes instead of failing them.
#
# BASE: the branch the change goes into (default origin/$GITHUB_BASE_REF in a pull request, else
# origin/main); on that branch itself (merge base = HEAD) the previous commit. Needs the history:
# a clone of depth 1 has no merge base (actions/checkout: fetch-depth: 0).
# Environment: SPEC (default spec.toml), OUT (default out/tissuebench-gate), BASELINE (default
# ci/baseline.toml: passed with --baseline when the file exists), LATENCY_FLOOR_S (default 0:
# this package's step takes microseconds, and tissuebench's default floor, 10 us, would let a
# 1.5x slowdown of a 6 us step pass; give the least increase that matters to you, in seconds),
# TISSUEBENCH (default: tissuebench, the command).
# Exit: 0 every unit holds, 1 a regression (error, failed unit, slower step), 2 bad input or no REF.
set -euo pipefail
cd "$(dirname "$0")/.."
spec=${SPEC:-spec.toml}
out=${OUT:-out/tissuebench-gate}
baseline=${BASELINE:-ci/baseline.toml}
tb=${TISSUEBENCH:-tissuebench}
base=${1:-${GITHUB_BASE_REF:+origin/$GITHUB_BASE_REF}}
base=${base:-origin/main}

if ! ref=$(git merge-base HEAD "$base"); then
    echo "gate: no merge base of HEAD and $base: fetch it (git fetch origin), and the history (fetch-depth: 0)" >&2
    exit 2
fi
if [ "$ref" = "$(git rev-parse HEAD)" ]; then
    ref=$(git rev-parse HEAD~1)  # on the base branch itself: gate the last commit
fi
with_baseline=()  # expanded as ${a[@]+"${a[@]}"}: an empty array is "unbound" to set -u in bash < 4.4 (macOS)
said=""
if [ -e "$baseline" ]; then
    with_baseline=(--baseline "$baseline")
    said=", baseline $baseline"
fi
echo "gate: $spec at $(git rev-parse --short HEAD) against $(git rev-parse --short "$ref") (merge base with $base)$said"

rm -rf "$out"
status=0
$tb sweep "$spec" --out "$out" --quiet || status=$?
if [ "$status" -gt 1 ]; then  # 1: a unit failed, stored: the check judges it against REF's run
    exit "$status"
fi
status=0
$tb check "$out" --against "$ref" ${with_baseline[@]+"${with_baseline[@]}"} --latency-floor-s "${LATENCY_FLOOR_S:-0}" \
    --junit "$out/_junit.xml" || status=$?
if [ "$status" -eq 1 ]; then
    echo "gate: if an error changed on purpose, record it in $baseline and commit that file with the change:"
    echo "gate:     $tb check $out --baseline $baseline --update-baseline && git add $baseline"
fi
exit "$status"
