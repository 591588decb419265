"""Reaction monitors are the force the supports exert: in statics they and the applied load add up
to zero, whatever the load (issue 44: with gravity the chest reaction was 5.981 N against 6.306 N
applied, the gravity lumped onto the clamped nodes dropped). Each load below also acts on nodes of
the clamped face (the top face's edge, the body's clamped layer), where the old monitor lost it."""
from __future__ import annotations

import numpy as np
import pytest

from tissuebench.cases.scene import load
from tissuebench.refsolvers.backends import make_backend
from tissuebench.reference.runner import solve

_SCENE = """
[case]
name = "reaction_block"
description = "block clamped at x = 0, loaded on its top face or by gravity"
[units]
length = "m"
force = "N"
[mesh]
builder = "box"
element = "{element}"
[mesh.params]
lengths = [0.04, 0.02, 0.02]
cell_type = "tetra"
[mesh.ci]
divisions = [{divisions}]
[mesh.paper]
divisions = [{divisions}]
[material]
name = "neo_hookean"
E = 5000.0
nu = 0.3
density = 1000.0
[[dirichlet]]
name = "clamped"
region = {{ plane = "x", value = 0.0, tol = 1e-9 }}
components = "xyz"
[[load]]
{load}
[analysis]
type = "static"
load_steps = 2
{formulation}
[[monitor]]
name = "rx"
quantity = "reaction_force"
region = {{ plane = "x", value = 0.0, tol = 1e-9 }}
component = "x"
[[monitor]]
name = "ry"
quantity = "reaction_force"
region = {{ plane = "x", value = 0.0, tol = 1e-9 }}
component = "y"
[[monitor]]
name = "rz"
quantity = "reaction_force"
region = {{ plane = "x", value = 0.0, tol = 1e-9 }}
component = "z"
"""
_TOP = '{ plane = "z", value = 0.02, tol = 1e-9 }'
LOADS = {
    "point": f'type = "point"\nregion = {_TOP}\nvalue = [0.05, 0.0, -0.2]',  # spread over the top face's nodes
    "traction": f'type = "traction"\nregion = {_TOP}\nvalue = [30.0, 0.0, -150.0]',
    "pressure": f'type = "pressure"\nregion = {_TOP}\nvalue = 200.0',
    "follower_pressure": f'type = "follower_pressure"\nregion = {_TOP}\nvalue = 200.0',
    "gravity": 'type = "body"\nvalue = [0.0, 0.0, -9810.0]',  # rho g [N/m^3]
}


def _scene(tmp_path, load_toml, element="P1", mixed=False):
    path = tmp_path / "block.toml"
    path.write_text(_SCENE.format(load=load_toml, element=element, divisions="2, 1, 1" if mixed else "4, 2, 2",
                                  formulation='formulation = "mixed"' if mixed else ""), encoding="utf-8")
    return load(path)


def _balance(scene, ref):
    """(sum of the reaction monitors, the applied load) at the last converged state, (3,) each."""
    be = make_backend("skfem", scene.to_problem())
    u = ref.displacement[-1].reshape(-1)
    lam = float(ref.steps[-1])
    applied = be.external_force(u, lam).reshape(-1, 3).sum(axis=0)
    row = ref.table[ref.table["converged"]].iloc[-1]
    return np.array([row["rx"], row["ry"], row["rz"]]), applied


@pytest.mark.parametrize("kind", list(LOADS))
def test_the_reactions_balance_the_applied_load(tmp_path, kind):
    scene = _scene(tmp_path, LOADS[kind])
    ref = solve(scene)
    assert ref.status == "success", ref.message
    reactions, applied = _balance(scene, ref)
    scale = np.abs(applied).max()
    assert scale > 0
    # what the clamped nodes carry directly: the old monitor (f_int only) missed exactly this
    pb = scene.to_problem()
    be = make_backend("skfem", pb)
    on_supports = be.external_force(ref.displacement[-1].reshape(-1), float(ref.steps[-1]))
    lumped = np.zeros(pb.ndof)
    lumped[pb.fixed_dofs] = on_supports[pb.fixed_dofs]
    assert np.abs(lumped.reshape(-1, 3).sum(axis=0)).max() > 1e-3 * scale  # the case the issue is about
    np.testing.assert_allclose(reactions + applied, 0.0, atol=1e-6 * scale)


def test_the_gravity_reaction_is_the_weight(tmp_path):
    """The applied load of the gravity case is the block's weight, rho g V (independent of the backend's
    sum): the reaction is its opposite."""
    scene = _scene(tmp_path, LOADS["gravity"])
    ref = solve(scene)
    reactions, _ = _balance(scene, ref)
    weight = 9810.0 * 0.04 * 0.02 * 0.02
    np.testing.assert_allclose(reactions, [0.0, 0.0, weight], rtol=1e-6, atol=1e-9 * weight)


def test_the_mixed_formulation_balances_gravity_too(tmp_path):
    """The u-p (Taylor-Hood) static run computes its reactions on its own path (refsolvers.mixed)."""
    scene = _scene(tmp_path, LOADS["gravity"], element="P2", mixed=True)
    ref = solve(scene)
    assert ref.status == "success", ref.message
    row = ref.table[ref.table["converged"]].iloc[-1]
    weight = 9810.0 * 0.04 * 0.02 * 0.02
    np.testing.assert_allclose([row["rx"], row["ry"], row["rz"]], [0.0, 0.0, weight], rtol=1e-6,
                               atol=1e-9 * weight)
