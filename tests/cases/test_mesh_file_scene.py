"""A user's own mesh file as a scene input (issue 27): ``[mesh] file = ...`` with its unit
stated and checked, and the scene details that cost a new user time."""
from __future__ import annotations

import shutil

import numpy as np
import pytest

from tissuebench.cases import load
from tissuebench.studies.describe import describe

from _mesh_scene import scene_file, write_block


def test_a_mesh_file_in_mm_becomes_a_scene_in_metres(tmp_path):
    write_block(tmp_path)
    s = load(scene_file(tmp_path))
    assert s.mesh_spec["builder"] == "file" and s.mesh_spec["params"]["scale"] == pytest.approx(1e-3)
    assert np.ptp(s.mesh.points, axis=0) == pytest.approx([0.04, 0.02, 0.02])
    assert s.mesh_label == "the mesh file block.msh (mm)"
    text = describe(str(tmp_path / "scene.toml"))
    assert "the mesh file block.msh (mm)" in text and "liver" not in text
    # the content of the file is the scene's identity, not where the folder lies
    h = s.content_hash()
    moved = tmp_path / "moved"
    moved.mkdir()
    for f in ("scene.toml", "block.msh"):
        shutil.copy(tmp_path / f, moved / f)
    assert load(moved / "scene.toml").content_hash() == h
    write_block(moved, size_mm=(41.0, 20.0, 20.0))
    assert load(moved / "scene.toml").content_hash() != h


def test_a_scale_instead_of_a_unit(tmp_path):
    write_block(tmp_path)
    s = load(scene_file(tmp_path, mesh='file = "block.msh"\nscale = 0.001\nelement = "P2"'))
    assert np.ptp(s.mesh.points, axis=0)[0] == pytest.approx(0.04) and s.element == "P2"


@pytest.mark.parametrize("mesh, message", [
    ('file = "block.msh"\nelement = "P1"', "mesh.file = 'block.msh': state the length unit"),
    ('file = "block.msh"\nunit = "inch"\nelement = "P1"', "mesh.unit = 'inch': unknown length unit"),
    ('file = "block.msh"\nunit = "mm"\nscale = 0.001\nelement = "P1"', "mesh.scale = 0.001: give the file's unit"),
    ('file = "missing.msh"\nunit = "mm"\nelement = "P1"', "mesh.file = 'missing.msh': mesh file .*missing.msh does "
                                                         "not exist"),
    ('file = "block.msh"\nbuilder = "liver"\nunit = "mm"\nelement = "P1"', "mesh.builder = 'liver': give either"),
    ('file = "block.msh"\nunit = "mm"\nelement = "P3"', "mesh.element = 'P3'"),
])
def test_mesh_file_mistakes_are_named(tmp_path, mesh, message):
    write_block(tmp_path)
    with pytest.raises(ValueError, match=message):
        load(scene_file(tmp_path, mesh=mesh))


def test_the_element_may_be_left_out(tmp_path):
    """Without [mesh] element a tetrahedral mesh gets P1 (issue 43: the reference may then choose a
    formulation that does not lock), and the scene says the element was not given."""
    write_block(tmp_path)
    s = load(scene_file(tmp_path, mesh='file = "block.msh"\nunit = "mm"'))
    assert s.element == "P1" and not s.element_given
    assert load(scene_file(tmp_path)).element_given


def test_a_unit_the_scene_cannot_convert_to(tmp_path):
    write_block(tmp_path)
    p = scene_file(tmp_path)
    p.write_text(p.read_text().replace('length = "m"', 'length = "1"'))
    with pytest.raises(ValueError, match="cannot convert to the scene's \\[units\\] length = '1'"):
        load(p)


def test_case_paper_is_optional_and_solver_is_not_a_key(tmp_path):
    write_block(tmp_path)
    s = load(scene_file(tmp_path))
    assert "paper" not in s.case
    with pytest.raises(ValueError, match="analysis.solver: unknown key"):
        load(scene_file(tmp_path, analysis_extra='solver = "bogus"'))


def test_a_variant_table_does_not_become_the_default(tmp_path):
    write_block(tmp_path)
    variant = ('[variants.dynamic]\n[variants.dynamic.analysis]\ntype = "dynamic"\ndt = 0.01\nt_end = 0.1\n'
               'integrator = "hht"\n')
    p = scene_file(tmp_path, extra=variant)
    s = load(p)
    assert s.variant is None and s.analysis["type"] == "static" and s.variants == ("dynamic",)
    assert load(p, variant="dynamic").analysis["type"] == "dynamic"
    p.write_text(p.read_text().replace("[units]", 'default_variant = "dynamic"\n[units]'))
    assert load(p).variant == "dynamic"
