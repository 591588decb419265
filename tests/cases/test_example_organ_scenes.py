"""The example organ scenes of examples/nearly_incompressible_organ (the dome at rest and in motion)
load and pass ``scene check`` on a coarse mesh of their own make_dome.py (every example runs as a test)."""
from __future__ import annotations

import importlib.util
import shutil
import sys
from pathlib import Path

import pytest

from tissuebench.cli import main

FOLDER = Path(__file__).resolve().parents[2] / "examples" / "nearly_incompressible_organ"


@pytest.fixture(scope="module")
def coarse_dome(tmp_path_factory):
    """A ~30 mm dome mesh (tens of nodes) written by the example's own script."""
    pytest.importorskip("gmsh")
    sys.path.insert(0, str(FOLDER.parent / "bring_your_own_organ"))  # make_dome.py imports gmsh_body.py
    try:
        spec = importlib.util.spec_from_file_location("make_dome", FOLDER / "make_dome.py")
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        folder = tmp_path_factory.mktemp("dome")
        module.dome_mesh(str(folder / "dome.msh"), 30.0)
    finally:
        sys.path.pop(0)
    return folder


@pytest.mark.parametrize("scene", ["dome.toml", "dome_motion.toml"])
def test_the_example_dome_scenes_pass_scene_check(coarse_dome, scene, capsys):
    shutil.copy(FOLDER / scene, coarse_dome / scene)
    assert main(["scene", "check", str(coarse_dome / scene), "--out", "-"]) == 0, capsys.readouterr().err
    said = capsys.readouterr()
    assert "error" not in said.err.lower()


@pytest.mark.parametrize("element, refused", [('element = "P1"\n', False), ("", True)])
def test_pod_galerkin_is_refused_up_front_on_an_average_nodal_pressure_reference(coarse_dome, element, refused):
    """At nu = 0.49 the reference takes the average nodal pressure tetrahedra unless the scene asks for
    P1: its force has no element split, and every pod_galerkin unit failed at build
    ("AnpBackend does not provide cell kernels"); now ``methods`` and a spec say so before any work."""
    from tissuebench.cases.scene import load
    from tissuebench.rom import method_class

    text = (FOLDER / "dome_motion.toml").read_text()
    assert 'element = "P1"\n' in text
    path = coarse_dome / f"motion{'_anp' if refused else ''}.toml"
    path.write_text(text.replace('element = "P1"\n', element))
    why = method_class("pod_galerkin").why_not(load(path))
    assert (why != "") == refused
    if refused:
        assert why.startswith("the reference uses average nodal pressure tetrahedra") and 'mesh.element = "P1"' in why
