"""The report's "Peers beside ours" section (issue 51): a unit of a method whose class declares a
counterpart is paired with a unit of that method on the same case, by the declaration alone (the
declared options, then the most equal shared options), with the ratios ours / peer and a verdict.
"""
from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from _plugin_dist import Installed
from _report_store import build_store, point_rows, unit_row
from tissuebench.reports.html import write_report
from tissuebench.reports.peers import SAME_ERROR, SAME_TIME, peer_pairs, verdict
from tissuebench.rom import RomMethod
from tissuebench.studies.results import ResultsStore
from tissuebench.studies.units import UnitOutcome

SOURCE = "test_peers_section:{}"


@pytest.fixture(autouse=True)
def _registry(tmp_path, monkeypatch):
    """The classes the pairing loads by "module:Class" leave the registry after each test (the plugin
    tests count the methods of other packages)."""
    installed = Installed(tmp_path / "site", monkeypatch)
    yield
    installed.undo()


class PeerOfGalerkin(RomMethod):
    """A library's adapter of the POD-Galerkin family (never built here)."""

    name = "peer_of_galerkin_report"
    kind = "trajectory"
    training_kinds = ("path", "trajectory")
    counterpart = {"trajectory": ("pod_galerkin", {}), "path": ("pod_newton", {})}

    def __init__(self, n_modes=4, hyper="deim"):
        pass

    def build(self, training):
        raise NotImplementedError


class PeerOfEcsw(PeerOfGalerkin):
    name = "peer_of_ecsw_report"
    counterpart = ("pod_galerkin", {"hyper": "ecsw"})


def _row(case, method, options, error, p99, offline=1.0, source="", status="ok"):
    row = unit_row(case, method, options, error, p99 / 2, p99, False)
    row.update(case=case, offline_s=offline, method_source=source, unit_status=status, load_average=1.5)
    return row


def _units(*rows):
    return pd.DataFrame(list(rows))


MANIFEST = {"cases": [{"id": "nh", "name": "liver_dynamic", "training": {"kind": "trajectory"}},
                      {"id": "palp", "name": "liver_palpation", "training": {"kind": "path"}}]}


def test_a_peer_is_paired_with_the_counterpart_unit_sharing_most_of_its_options():
    peer = _row("nh", "peer_of_galerkin_report", {"n_modes": 20, "hyper": "deim"}, 0.04, 8e-3, 30.0,
                SOURCE.format("PeerOfGalerkin"))
    units = _units(peer,
                   _row("nh", "pod_galerkin", {"n_modes": 20, "hyper": "none"}, 0.01, 50e-3),
                   _row("nh", "pod_galerkin", {"n_modes": 20, "hyper": "deim"}, 0.02, 2e-3, 20.0),
                   _row("nh", "pod_galerkin", {"n_modes": 10, "hyper": "deim"}, 0.05, 1e-3),
                   _row("palp", "pod_galerkin", {"n_modes": 20, "hyper": "deim"}, 0.001, 1e-4))  # another case
    pairs, notes = peer_pairs(units, MANIFEST, "max_rel_l2")
    assert notes == [] and len(pairs) == 1
    p = pairs.iloc[0]
    assert p["ours"] == "pod_galerkin hyper=deim n_modes=20" and p["peer_method"] == "peer_of_galerkin_report"
    assert p["error_ratio"] == pytest.approx(0.5) and p["p99_ratio"] == pytest.approx(0.25)
    assert p["offline_ratio"] == pytest.approx(20 / 30) and p["verdict"] == "ours ahead"
    assert p["peer_load"] == 1.5


def test_the_declared_options_filter_and_the_training_kind_chooses_the_declaration():
    ecsw = _row("nh", "peer_of_ecsw_report", {"n_modes": 20}, 0.02, 1e-3, source=SOURCE.format("PeerOfEcsw"))
    on_path = _row("palp", "peer_of_galerkin_report", {"n_modes": 4}, 0.02, 1e-3,
                   source=SOURCE.format("PeerOfGalerkin"))
    units = _units(ecsw, on_path,
                   _row("nh", "pod_galerkin", {"n_modes": 20, "hyper": "deim"}, 0.02, 1e-3),  # more shared, not ecsw
                   _row("nh", "pod_galerkin", {"n_modes": 10, "hyper": "ecsw"}, 0.03, 2e-3),
                   _row("palp", "pod_galerkin", {"n_modes": 4}, 0.02, 1e-3),  # not the path's counterpart
                   _row("palp", "pod_newton", {"n_modes": 4}, 0.02, 0.5))
    pairs, notes = peer_pairs(units, MANIFEST, "max_rel_l2")
    assert notes == []
    by_peer = pairs.set_index("peer_method")["ours"].to_dict()
    assert by_peer == {"peer_of_ecsw_report": "pod_galerkin hyper=ecsw n_modes=10",
                       "peer_of_galerkin_report": "pod_newton n_modes=4"}


def test_a_peer_without_its_counterpart_or_its_class_is_named_not_paired():
    units = _units(_row("nh", "peer_of_ecsw_report", {"n_modes": 20}, 0.02, 1e-3, source=SOURCE.format("PeerOfEcsw")),
                   _row("nh", "pod_galerkin", {"n_modes": 20, "hyper": "deim"}, 0.02, 1e-3),
                   _row("nh", "gone_peer", {}, 0.02, 1e-3, source="tissuebench_no_such_package.mod:Gone"))
    pairs, notes = peer_pairs(units, MANIFEST, "max_rel_l2")
    assert pairs.empty
    assert notes[0] == ('nh: peer_of_ecsw_report n_modes=20: no unit of its counterpart pod_galerkin {"hyper": '
                        '"ecsw"} in this case: not paired')
    assert notes[1].startswith("nh: gone_peer: its method could not be loaded (") and notes[1].endswith("not paired")


def test_a_unit_whose_class_is_gone_is_paired_by_what_its_build_recorded():
    gone = _row("nh", "gone_peer", {"n_modes": 20}, 0.02, 1e-3, source="tissuebench_no_such_package.mod:Gone")
    gone["model_info"] = json.dumps({"counterpart": ["pod_galerkin", {"hyper": "ecsw"}]})
    units = _units(gone, _row("nh", "pod_galerkin", {"n_modes": 20, "hyper": "deim"}, 0.02, 1e-3),
                   _row("nh", "pod_galerkin", {"n_modes": 20, "hyper": "ecsw"}, 0.01, 1e-3))
    pairs, notes = peer_pairs(units, MANIFEST, "max_rel_l2")
    assert notes == [] and pairs["ours"].tolist() == ["pod_galerkin hyper=ecsw n_modes=20"]


def _side(error, p99, offline=1.0, status="ok"):
    return {"status": status, "error": error, "p99": p99, "offline": offline}


@pytest.mark.parametrize("ours, expected", [
    (_side(0.02 * (1 + 0.9 * SAME_ERROR), 1e-3), "same"),  # within both tolerances
    (_side(0.02 * (1 - 1.1 * SAME_ERROR), 1e-3), "ours ahead"),  # just past the error's
    (_side(0.02 * (1 + 1.1 * SAME_ERROR), 1e-3), "peer ahead"),
    (_side(0.02, 1e-3 / SAME_TIME * 1.01), "same"),  # within the latency's factor
    (_side(0.02, 1e-3 / SAME_TIME * 0.99), "ours ahead"),  # just past it
    (_side(0.02, 1e-3 * SAME_TIME * 1.01), "peer ahead"),
    (_side(0.01, 2e-3), "trade-off: ours more accurate, the peer faster"),
    (_side(0.04, 0.5e-3), "trade-off: the peer more accurate, ours faster"),
    (_side(0.02, 1e-3, offline=0.99 / SAME_TIME), "ours ahead (the same error and step, cheaper offline)"),
    (_side(0.02, 1e-3, offline=1.01 / SAME_TIME), "same"),  # offline within the factor
    (_side(np.nan, np.nan, status="failed"), "ours failed"),
])
def test_the_verdict_on_both_sides_of_its_tolerances(ours, expected):
    assert verdict(_side(0.02, 1e-3), ours) == expected
    assert verdict(_side(0.02, 1e-3, status="failed"), _side(0.02, 1e-3, status="failed")) == "peer and ours failed"


def test_the_report_shows_the_pairs_with_their_table(tmp_path):
    root = build_store(tmp_path / "results", failed_unit=False)
    peer = unit_row("cornea", "peer_of_accurate_report", {"n_modes": 9}, 0.002, 1e-4, 2e-4, False)
    peer.update(unit_key="cornea-peer", method_source=SOURCE.format("PeerOfAccurate"))
    ResultsStore(root).write_unit(UnitOutcome(peer, point_rows(0.002)))
    manifest = json.loads((root / "_sweep.json").read_text())
    manifest["cases"] = [{"id": "cornea", "name": "cornea_pinch", "training": {"kind": "path"}}]
    (root / "_sweep.json").write_text(json.dumps(manifest))
    html = write_report(root, tmp_path / "r.html").read_text()
    assert '<h2 id="peers">Peers beside ours</h2>' in html and 'href="#peers"' in html
    assert "<td>peer_of_accurate_report n_modes=9</td><td>accurate n_modes=9</td>" in html
    assert "1 pair(s): peer ahead 1." in html  # the peer: 0.2 % at 0.2 ms against 0.4 % at 2.5 ms
    table = pd.read_csv(tmp_path / "r_data" / "peers.csv")
    assert table.loc[0, "p99_ratio"] == pytest.approx(2.5e-3 / 2e-4)


def test_a_report_without_a_peer_has_no_such_section(tmp_path):
    html = write_report(build_store(tmp_path / "results"), tmp_path / "r.html").read_text()
    assert 'id="peers"' not in html and not (tmp_path / "r_data" / "peers.csv").exists()


class PeerOfAccurate(PeerOfGalerkin):
    name = "peer_of_accurate_report"
    counterpart = ("accurate", {})
