"""The common sections of a scene on a box-built block, for the tests that write their own scene
TOML (shared by tests/cases/test_history_resolution.py, tests/cases/test_load_histories.py and
tests/reference/test_reaction_monitors.py): each test appends what is its own (its loads, analysis,
monitors, variants)."""
from __future__ import annotations


def _floats(values) -> str:
    return ", ".join(str(v) for v in values)


def box_scene(name: str, description: str, lengths, divisions, E: float, nu: float, *, element: str = "P1",
              material: str = "neo_hookean", density: float = 1000.0, time: bool = True, clamp: str = "x",
              clamp_name: str | None = None) -> str:
    """The TOML of a block of ``lengths`` [m] (tetrahedra, ``divisions`` at both resolutions) of
    ``material`` (``E`` [Pa], ``nu``, ``density`` [kg/m^3]) clamped in every component on its face
    ``clamp = 0`` (a ``[[dirichlet]]`` named ``clamp_name`` when given): the sections ``[case]``,
    ``[units]`` (metres, newtons, and seconds with ``time``), ``[mesh]``, ``[material]`` and that
    ``[[dirichlet]]``, in this order, ending in a newline."""
    return f"""
[case]
name = "{name}"
description = "{description}"
[units]
length = "m"
force = "N"
{'time = "s"' if time else ""}
[mesh]
builder = "box"
element = "{element}"
[mesh.params]
lengths = [{_floats(lengths)}]
cell_type = "tetra"
[mesh.ci]
divisions = [{_floats(divisions)}]
[mesh.paper]
divisions = [{_floats(divisions)}]
[material]
name = "{material}"
E = {E}
nu = {nu}
density = {density}
[[dirichlet]]
{f'name = "{clamp_name}"' if clamp_name else ""}
region = {{ plane = "{clamp}", value = 0.0, tol = 1e-9 }}
components = "xyz"
"""
