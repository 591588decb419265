"""Provenance of a method from another package (issue 38): the unit key and the stored row hold its
distribution, version and code hash, so ``sweep --resume`` recomputes its units after its code
changed and says why (it kept them as current before: "0 computed, 2 kept from before"), and the
report names its version."""
from __future__ import annotations

import importlib
import sys

import pytest

from _gate_spec import cornea_spec
from _plugin_dist import Installed, toy_source, write_dist
from tissuebench.cli import main
from tissuebench.reports.report_sections import provenance_rows
from tissuebench.rom.plugins import _files_hash
from tissuebench.studies.results import read_units

SPEC = cornea_spec("prov", ["tb_prov_plug", "nearest"])


@pytest.fixture
def installed(tmp_path, monkeypatch):
    inst = Installed(tmp_path / "site", monkeypatch)
    write_dist(inst.root, "tb-prov", "0.3.1", {"tb_prov_plug": "tb_prov:Toy"}, {"tb_prov": toy_source("tb_prov_plug")})
    yield inst
    inst.undo()


@pytest.fixture(autouse=True)
def no_derived_figures(monkeypatch):
    """The derived figures (seconds of matplotlib per sweep) are not what this file tests."""
    import tissuebench.reports.derived_figures as figures

    monkeypatch.setattr(figures, "draw_derived", lambda *args, **kwargs: [])


def _sweep(spec, out, capsys, *extra):
    assert main(["sweep", str(spec), "--out", str(out), "--quiet", *extra]) == 0
    return capsys.readouterr().out


def test_a_changed_plugin_is_recomputed_on_resume_saying_why(installed, tmp_path, capsys):
    spec = tmp_path / "prov.toml"
    spec.write_text(SPEC)
    out = tmp_path / "res"
    _sweep(spec, out, capsys)
    rows = read_units(out).set_index("method")
    plug = rows.loc["tb_prov_plug"]
    assert (plug["unit_status"], plug["method_distribution"], plug["method_version"], plug["method_source"]) == (
        "ok", "tb-prov", "0.3.1", "tb_prov:Toy")
    assert len(plug["method_code_hash"]) == 64 and rows.loc["nearest", "method_source"] == ""
    said = _sweep(spec, out, capsys, "--resume")  # nothing changed: kept
    assert "0 computed (0 failed), 2 kept from before, 0 recomputed" in said and "recomputed 1" not in said
    before = plug["method_code_hash"]
    module = installed.root / "tb_prov.py"
    module.write_text(module.read_text().replace("self.gain * lam", "self.gain * lam * 1.0"))  # its code changes
    _files_hash.cache_clear()  # what a new process sees: the code on disk
    importlib.reload(sys.modules["tb_prov"])
    said = _sweep(spec, out, capsys, "--resume")
    after = read_units(out).set_index("method").loc["tb_prov_plug", "method_code_hash"]
    assert after != before
    assert "1 computed (0 failed), 1 kept from before, 1 recomputed" in said
    assert f"recomputed 1 unit: plugin tb-prov changed (code hash {before[:8]} -> {after[:8]})" in said
    rows = dict(provenance_rows({}, read_units(out)))  # the report's provenance table
    assert rows["units: methods from other packages"] == f"tb_prov_plug: tb-prov 0.3.1 (tb_prov:Toy, code {after[:12]})"
