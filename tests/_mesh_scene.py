"""A user's own mesh file as a scene (shared by tests/cases/test_mesh_file_scene.py and
tests/studies/test_scene_sweep.py): a small tetrahedral block in millimetres and the scene
TOML around it."""
from __future__ import annotations

import meshio

from tissuebench.cases.meshes import box_mesh

SCENE = """
[case]
name = "block"
description = "a block of my own, clamped at x = 0, pressed on top"
{case_extra}
[units]
length = "m"
force = "N"
[mesh]
{mesh}
[material]
name = "neo_hookean"
E = 10000.0
nu = 0.45
[[dirichlet]]
region = {{ fraction = "x", side = "min", amount = 0.05 }}
[[load]]
type = "point"
region = {{ nearest = [0.5, 1.0, 0.5], frame = "bbox", count = 1, boundary = true }}
value = [0.0, -0.1, 0.0]
[analysis]
type = "static"
load_steps = 2
{analysis_extra}
{extra}
"""


#: the block's tip displacement, a monitor for the scenes whose checks read one (the convergence tests)
TIP_MONITOR = """[[monitor]]
name = "tip_uy"
quantity = "displacement"
point = [0.04, 0.02, 0.01]
component = "y"
unit = "m"
"""


def write_block(folder, name="block.msh", size_mm=(40.0, 20.0, 20.0)):
    """A small tetrahedral block in millimetres, written as a gmsh file with meshio."""
    m = box_mesh(size_mm, (4, 2, 2), "tetra")
    path = folder / name
    meshio.write(path, meshio.Mesh(m.points, [("tetra", m.cells)]), file_format="gmsh22", binary=False)
    return path


def scene_file(folder, mesh='file = "block.msh"\nunit = "mm"\nelement = "P1"', case_extra="", analysis_extra="",
               extra=""):
    p = folder / "scene.toml"
    p.write_text(SCENE.format(mesh=mesh, case_extra=case_extra, analysis_extra=analysis_extra, extra=extra))
    return p
