"""Reaction monitors are the force the supports exert: in statics they and the applied load add up
to zero, whatever the load (issue 44: with gravity the chest reaction was 5.981 N against 6.306 N
applied, the gravity lumped onto the clamped nodes dropped). Each load below also acts on nodes of
the clamped face (the top face's edge, the body's clamped layer), where the old monitor lost it."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from tissuebench.cases.scene import load
from tissuebench.refsolvers.backends import make_backend
from tissuebench.reference.runner import solve

from _box_scene import box_scene


def _block(divisions=(4, 2, 2), element="P1", material="neo_hookean") -> str:
    """The block, 40 x 20 x 20 mm clamped at x = 0 (:func:`_box_scene.box_scene`)."""
    return box_scene("reaction_block", "block clamped at x = 0, loaded on its top face or by gravity",
                     (0.04, 0.02, 0.02), divisions, 5000.0, 0.3, element=element, material=material, time=False,
                     clamp_name="clamped")


#: what the scene adds to the block: its load, analysis and reaction monitors
_SCENE = """[[load]]
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
    text = _SCENE.format(load=load_toml, formulation='formulation = "mixed"' if mixed else "")
    path.write_text(_block((2, 1, 1) if mixed else (4, 2, 2), element) + text, encoding="utf-8")
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


# ---------------------------------------------------------------- dynamics (issue 54)
def _dynamic_scene(tmp_path, integrator, dt, extra=""):
    """The block under the top-face traction applied at once (a step), integrated for 20 steps, with a
    displacement monitor beside the reactions (the trajectory training's output functional)."""
    load_toml = LOADS["traction"] + '\nhistory = { type = "step", t0 = 0.0 }'
    text = _block(material="linear") + _SCENE.format(load=load_toml, formulation="")
    text = text.replace(
        'type = "static"\nload_steps = 2', f'type = "dynamic"\nintegrator = "{integrator}"\ndt = {dt}\n'
                                           f't_end = {20 * dt}\n{extra}')
    text += '[[monitor]]\nname = "tip_ux"\nquantity = "displacement"\npoint = [0.04, 0.01, 0.02]\ncomponent = "x"\n'
    path = tmp_path / "block_dynamic.toml"
    path.write_text(text, encoding="utf-8")
    return load(path)


@pytest.mark.parametrize("integrator, dt", [("newmark", 1e-3), ("central_difference", 2e-5)])
def test_dynamic_reactions_are_the_load_plus_the_inertia(tmp_path, integrator, dt):
    """Momentum balance of the whole block: the supports' reactions plus the applied load are the rate of
    momentum, sum_j m_j a_j with m_j the row sums of the mass (sum m_j = rho V), K's rows summing to zero
    on a translation; a24e7fa raised "monitor 'rx' needs the support reactions"."""
    from tissuebench.studies.trajectories import reference_run, run_monitors, scene_system, trajectory_training

    scene = _dynamic_scene(tmp_path, integrator, dt)
    ss = scene_system(scene)
    res = reference_run(ss)
    assert res.success, res.message
    rows = run_monitors(ss, res)
    assert len(rows) == 21 and set(rows[0]) == {"rx", "ry", "rz", "tip_ux"}
    nodal_mass = np.asarray(ss.system.M.sum(axis=1)).ravel().reshape(-1, 3)
    np.testing.assert_allclose(nodal_mass.sum(axis=0), 1000.0 * 0.04 * 0.02 * 0.02, rtol=1e-12)
    be = ss.backend
    inertia_seen = 0.0
    for row, t, u, a in zip(rows, res.t_stored, res.u, res.a):
        applied = be.external_force(u, float(scene.history(t))).reshape(-1, 3).sum(axis=0)
        inertia = (nodal_mass * a.reshape(-1, 3)).sum(axis=0)
        reactions = np.array([row["rx"], row["ry"], row["rz"]])
        np.testing.assert_allclose(reactions + applied, inertia, rtol=0, atol=1e-9 * np.abs(applied).max())
        inertia_seen = max(inertia_seen, np.abs(inertia).max() / np.abs(applied).max())
    assert inertia_seen > 0.1   # the inertia is a real part of the reactions here, not round-off
    # the training builds its output functional beside the reaction monitors
    training = trajectory_training(ss)
    assert set(training.outputs) == {"tip_ux"}
    np.testing.assert_allclose(training.outputs["tip_ux"] @ res.u[-1], rows[-1]["tip_ux"], rtol=1e-12)


def test_dynamic_reactions_at_rest_are_the_static_ones(tmp_path):
    """v = a = 0: the reaction of the static path, f_int - f_ext on the fixed dofs; in motion the supports'
    inertia and damping come on top (here M a: a consistent mass couples the clamped rows)."""
    from tissuebench.studies.trajectories import scene_system

    ss = scene_system(_dynamic_scene(tmp_path, "newmark", 1e-3))
    pb, be, n = ss.backend.problem, ss.backend, ss.system.n
    u = np.random.default_rng(0).normal(scale=1e-4, size=n)
    u[pb.fixed_dofs] = 0.0
    static = pb.support_reactions(be.internal_force(u), be.external_force(u, 1.0))
    np.testing.assert_allclose(ss.system.reactions(0.01, u, np.zeros(n), np.zeros(n)), static, rtol=1e-13,
                               atol=1e-15)
    a = np.zeros(n)
    a[pb.free_dofs] = 1.0
    moving = ss.system.reactions(0.01, u, np.zeros(n), a)
    np.testing.assert_allclose(moving - static, (ss.system.M @ a) * np.isin(np.arange(n), pb.fixed_dofs),
                               rtol=1e-13, atol=1e-15)
    assert np.abs(moving - static).max() > 1e-6


def test_dynamic_reaction_monitors_need_the_state(tmp_path):
    """Both sides: the reaction monitors need t, v and a (named when missing), and a run's monitors its full state;
    a scene without them evaluates from u alone."""
    from tissuebench.refsolvers.dynamics import integrate
    from tissuebench.studies.trajectories import run_monitors, scene_system

    ss = scene_system(_dynamic_scene(tmp_path, "newmark", 1e-3))
    n = ss.system.n
    u = np.zeros(n)
    with pytest.raises(ValueError, match=r"^reaction_block: monitors \['rx', 'ry', 'rz'\] read the support "
                                         r"reactions of a dynamic state, which need t, v, a \("):
        ss.monitors(u)
    with pytest.raises(ValueError, match=r"which need a \("):
        ss.monitors(u, 0.0, np.zeros(n))
    assert ss.monitors(u, 0.0, np.zeros(n), np.zeros(n))["tip_ux"] == 0.0
    part = integrate(ss.system, None, None, 1e-3, 2e-3, method="newmark", dofs=[0, 1])
    with pytest.raises(ValueError, match=rf"^res stores 2 of the {n} dofs: the monitors need the full state "):
        run_monitors(ss, part)
    scene = _dynamic_scene(tmp_path, "newmark", 1e-3)
    scene = dataclasses.replace(scene, monitors=[m for m in scene.monitors if m["name"] == "tip_ux"])
    assert scene_system(scene).monitors(u) == {"tip_ux": 0.0}
