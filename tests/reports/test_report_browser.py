"""The report in a real browser: headless Chromium loads it from disk (file://), with no network.

Asserted on the DOM Chromium dumps after running the page's scripts: no JavaScript error or
console.error (the page collects them into ``#js-errors``; a control page with a deliberate
error proves the collector catches one), every figure drawn, the Pareto plot's points
(plotly's ``path.point``) as many as the units with an error and a latency, the
recommendation text present, the hostile strings shown as text. A screenshot is saved
(``$TISSUEBENCH_SCREENSHOT_DIR`` keeps a copy, e.g. as a CI artifact).
"""
from __future__ import annotations

import os
import re
import shutil
import subprocess
from html.parser import HTMLParser
from pathlib import Path

import pytest

from _gate_spec import BEYOND, cornea_spec
from _report_store import EVIL, build_store, rename_case
from tissuebench.reports.html import write_report

CHROMIUM = os.environ.get("TISSUEBENCH_CHROMIUM") or next(
    (shutil.which(n) for n in ("chromium", "chromium-browser", "google-chrome") if shutil.which(n)), None)
pytestmark = [pytest.mark.browser, pytest.mark.skipif(
    CHROMIUM is None, reason="headless Chromium not found (Debian: apt-get install -y chromium; or set "
                             "TISSUEBENCH_CHROMIUM): the report's browser test is skipped")]
_FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
          "--disable-component-update", "--disable-sync", "--no-first-run", "--hide-scrollbars",
          "--virtual-time-budget=10000"]
_VOID = {"area", "base", "br", "col", "embed", "hr", "img", "input", "link", "meta", "source", "track", "wbr"}


def chromium(page: Path, tmp: Path, *args: str) -> str:
    """Run headless Chromium on ``page`` (its own profile folder); its stdout."""
    cmd = [CHROMIUM, *_FLAGS, f"--user-data-dir={tmp / 'profile'}", *args, page.resolve().as_uri()]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=180)
    assert done.returncode == 0, done.stderr[-2000:]
    return done.stdout


class _Element(HTMLParser):
    """Inside the element with ``id``: the ``path.point`` count and the text."""

    def __init__(self, element_id: str):
        super().__init__()
        self.id, self.depth, self.points, self.text = element_id, 0, 0, []

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if self.depth == 0 and a.get("id") == self.id:
            self.depth = 1
        elif self.depth and tag not in _VOID:
            self.depth += 1
        if self.depth and tag == "path" and "point" in (a.get("class") or "").split():
            self.points += 1

    def handle_startendtag(self, tag, attrs):
        if self.depth and tag == "path" and "point" in (dict(attrs).get("class") or "").split():
            self.points += 1

    def handle_endtag(self, tag):
        if self.depth and tag not in _VOID:
            self.depth -= 1

    def handle_data(self, data):
        if self.depth:
            self.text.append(data)


def element(dom: str, element_id: str) -> _Element:
    parser = _Element(element_id)
    parser.feed(dom)
    return parser


def _attr(dom: str, element_id: str, name: str) -> str | None:
    tag = re.search(rf'<[^>]*\bid="{re.escape(element_id)}"[^>]*>', dom)
    m = tag and re.search(rf'\b{name}="([^"]*)"', tag.group(0))
    return m.group(1) if m else None


def _check_page(page: Path, tmp: Path, n_cases: int, shot: str) -> str:
    """Load ``page`` once: the DOM after its scripts ran (checked here) and a screenshot ``shot``.png."""
    dom = chromium(page, tmp, "--dump-dom", f"--screenshot={tmp / shot}.png", "--window-size=1400,2400")
    _keep_screenshot(tmp / f"{shot}.png")
    errors = element(dom, "js-errors")
    assert _attr(dom, "js-errors", "data-count") == "0", "".join(errors.text)
    assert re.search(rf'<body[^>]*data-plots-done="{2 * n_cases}"', dom), "the figures were not all drawn"
    for i in range(n_cases):
        expected = int(_attr(dom, f"pareto-{i}", "data-expected-points"))
        assert expected > 0 and element(dom, f"pareto-{i}").points == expected
        assert element(dom, f"error-{i}").points > 0
    return dom


def _keep_screenshot(shot: Path) -> None:
    assert shot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and shot.stat().st_size > 20_000
    keep = os.environ.get("TISSUEBENCH_SCREENSHOT_DIR")
    if keep:
        Path(keep).mkdir(parents=True, exist_ok=True)
        shutil.copy(shot, Path(keep) / shot.name)
    print(f"screenshot: {shot}")


def test_handmade_report_in_chromium(tmp_path):
    root = build_store(tmp_path / "results", evil=True)
    rename_case(root, "cornea", "%3Cscript%3Ealert(1)%3C%2Fscript%3E")  # the case id itself is hostile
    page = write_report(root, tmp_path / "report.html", require="rate>=500Hz, error<=2%")
    dom = _check_page(page, tmp_path, n_cases=1, shot="report_handmade")
    assert element(dom, "pareto-0").points == 5  # 5 finished units; the failed one is not drawn
    rec = " ".join("".join(element(dom, "recommendation-0").text).split())
    # the section is titled by the scene, the case id in small print (issue 44's wording)
    assert f"{EVIL} (case {EVIL}): 1 of 6 units meet it" in rec
    assert "fast_rough n_modes=4: p99 1.5 ms (667 Hz; 200 steps, 2 beyond the p99" in rec
    assert EVIL not in dom  # shown as text (&lt;script&gt;...) everywhere, never as an element
    assert dom.count("&lt;script&gt;alert(1)&lt;/script&gt;") >= 5


def test_the_error_collector_catches_an_error(tmp_path):
    """Control: the same page with a deliberate error reports it (the check above can fail)."""
    root = build_store(tmp_path / "results")
    page = write_report(root, tmp_path / "report.html")
    broken = tmp_path / "broken.html"
    broken.write_text(page.read_text().replace("</body>", "<script>no_such_function();</script></body>"))
    dom = chromium(broken, tmp_path, "--dump-dom")
    assert _attr(dom, "js-errors", "data-count") == "1"
    assert "no_such_function is not defined" in "".join(element(dom, "js-errors").text)


TINY = cornea_spec("report_tiny", [("anm_pod", "options = { eps = 1e-6, max_segments = 1 }\n"
                                               "grid = { n_modes = [2, 4], order = [1, 6] }"), "nearest"],
                   latency_steps=30, warmup=3, evaluation=BEYOND,
                   sweep='description = "cornea_pinch at ci: ANM-POD against the baselines (report test)"')


@pytest.mark.slow  # ~20 s: a 5-unit sweep at ci, then the browser
def test_report_of_a_real_sweep_in_chromium(tmp_path):
    from tissuebench.studies.results import read_units
    from tissuebench.studies.spec import load_spec
    from tissuebench.studies.sweep import run_sweep

    spec = tmp_path / "tiny.toml"
    spec.write_text(TINY)
    run_sweep(load_spec(spec), tmp_path / "results", progress=False)
    units = read_units(tmp_path / "results")
    page = write_report(tmp_path / "results", tmp_path / "report.html", require="rate>=500Hz, error<=2%")
    dom = _check_page(page, tmp_path, n_cases=1, shot="report_cornea_pinch")
    assert element(dom, "pareto-0").points == int((units["unit_status"] == "ok").sum()) == 5
    rec = " ".join("".join(element(dom, "recommendation-0").text).split())
    assert rec.startswith("cornea_pinch: ") and ("meet it, ranked by margin" in rec or "None meets it" in rec)
    # the requirement in words, the metric's id beside them (issue 44: the report read by a person)
    assert "haptic rate &gt;= 500 Hz on the p99 step" in dom
    # the default headline metric (issue 52: peak-normalised over the claimed range) in words, its id beside them
    assert ("(worst error of the field over the range it claims, relative to the largest displacement there, "
            "claimed_error)") in dom
