"""``"pod_galerkin"``: POD-Galerkin with hyper-reduction for nonlinear structural dynamics.

Offline (:meth:`PodGalerkin.build`): a POD basis of the training's displacement snapshots
(velocities too, where the training has them and ``velocities`` is on), the reduced mass and
loads, and the reduced internal force: every element (``hyper = "none"``, the accuracy ceiling),
an ECSW rule (:mod:`.ecsw`) or a DEIM interpolation (:mod:`.deim`) fitted on the training
states projected on the basis. Online (:class:`~.model.GalerkinModel`): the reference's own
implicit integrator on the :class:`~.system.ReducedSystem`, Newton with the reduced tangent.
"""
from __future__ import annotations

import time

import numpy as np

from ...reference.formulation import formulation_of
from ...refsolvers.dynamics import INTEGRATORS, make_integrator
from ..base import Applies, RomMethod, Training, check_choice, register
from ..fe_baselines.stepping import ScaledHistory
from ..training_scene import scene_of
from .basis import snapshot_basis, training_states
from .deim import deim_forces
from .ecsw import ecsw_rule
from .forces import LinearForces, element_forces
from .model import GalerkinModel
from .system import reduced_system

__all__ = ["PodGalerkin", "HYPER", "IMPLICIT"]

HYPER = ("none", "ecsw", "deim")
IMPLICIT = tuple(name for name, cls in INTEGRATORS.items() if cls.implicit)
_INNER = ("euclidean", "mass")


def _number(name, value, low, integer=False, allow_none=False):
    if value is None and allow_none:
        return None
    ok = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)
    if not ok or not np.isfinite(value) or value <= low or (integer and int(value) != value):
        kind = f"an integer > {low}" if integer else f"a finite number > {low}"
        raise ValueError(f"pod_galerkin option {name} must be {kind}{' or None' if allow_none else ''}, got {value!r}")
    return int(value) if integer else float(value)


def _at_least_one(name, value):
    ok = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)
    if not ok or not np.isfinite(value) or value < 1:
        raise ValueError(f"pod_galerkin option {name} must be a finite number >= 1, got {value!r}")
    return float(value)


@register
class PodGalerkin(RomMethod):
    """POD-Galerkin trajectory ROM with ECSW or DEIM hyper-reduction (module docstring).

    Options
    -------
    n_modes : int or None
        Basis size (None: the smallest capturing ``energy``).
    energy : float in (0, 1]
        POD energy criterion when ``n_modes`` is None.
    inner : {"euclidean", "mass"}
        Inner product of the POD and of the projection of the initial state.
    velocities : bool
        Add the training's velocity snapshots (scaled to the displacements' norm) to the POD.
    hyper : {"none", "ecsw", "deim"}
        Reduced internal force: every element, an ECSW rule, or DEIM.
    ecsw_tol : float
        Largest relative residual of the ECSW fit on the training states.
    deim_modes : int or None
        Force modes of DEIM (None: twice the basis size), of the internal force less its linear
        part at rest, which is reduced exactly (:mod:`.deim`).
    deim_oversampling : float >= 1
        Sampled dofs of DEIM per force mode: 1 interpolates the force modes at as many dofs;
        above 1 (default 2) the force is fitted by least squares at more dofs (gappy POD), which
        bounds the amplification of what the force modes miss, at the cost of a larger reduced
        mesh (measured in :mod:`.deim`).
    hyper_states : int
        At most this many training states (evenly through the runs) fit the hyper-reduction.
    integrator : str or None
        Implicit integrator (None: the scene's, with its options; HHT where the scene's is explicit).
    rtol : float
        Relative residual tolerance of the reduced Newton iteration.
    max_iterations : int
        Newton iterations per (sub)step.
    newton_tangent : {"reuse", "iteration"}
        The reduced tangent kept across iterations and steps, formed again on a poor contraction
        (modified Newton), or formed at every iteration (:mod:`~tissuebench.refsolvers.dynamics.step_newton`).
    newton_iterations : int or None
        None: Newton to ``rtol`` (at most ``max_iterations``); k: exactly k iterations every step,
        accepted converged or not (a haptic loop's fixed budget: the step's cost no longer depends
        on the state, so its p99 stays near its median); a step left above ``rtol`` says so in its
        message, and the error against the reference states the price.
    """

    name = "pod_galerkin"
    kind = "trajectory"
    nested = ()
    training_kinds = ("trajectory",)
    applies = Applies(dead_loads=True)
    refinements = {"ecsw_tol": 0.5}

    @classmethod
    def refinements_for(cls, options) -> dict:
        """ECSW's tolerance, halved by each refinement (more elements in the cubature), with ``hyper =
        "ecsw"`` (the default) only: it changes no other model."""
        return dict(cls.refinements) if (options or {}).get("hyper", "ecsw") == "ecsw" else {}

    @classmethod
    def why_not(cls, scene, options=None) -> str:
        """Besides :attr:`applies`: the reduced forces are sums over elements (every one, or an ECSW
        or DEIM sample), which the average nodal pressure formulation of a nearly incompressible
        scene's reference does not have (its pressure couples the elements around each node)."""
        why = super().why_not(scene, options)
        if why or not getattr(scene, "is_fe", False):
            return why
        if formulation_of(scene).name == "anp":
            return ("the reference uses average nodal pressure tetrahedra (nearly incompressible: P1 locks), whose "
                    "force does not split into element forces for the reduced model to sum or sample; ask for "
                    'mesh.element = "P1" (the locking P1 as reference) to use it')
        return ""

    def __init__(self, n_modes=None, energy=0.99999, inner="euclidean", velocities=False, hyper="ecsw",
                 ecsw_tol=5e-3, deim_modes=None, deim_oversampling=2.0, hyper_states=60, integrator=None, rtol=1e-6,
                 max_iterations=20, newton_tangent="reuse", newton_iterations=None):
        for name, value, valid in (("inner", inner, _INNER), ("hyper", hyper, HYPER),
                                   ("velocities", velocities, (True, False)),
                                   ("newton_tangent", newton_tangent, ("reuse", "iteration"))):
            check_choice("pod_galerkin option", name, value, valid)
        if integrator is not None:
            check_choice("pod_galerkin option", "integrator", integrator, IMPLICIT)
        if not (isinstance(energy, (int, float)) and not isinstance(energy, bool) and 0 < energy <= 1):
            raise ValueError(f"pod_galerkin option energy must lie in (0, 1], got {energy!r}")
        self.options = dict(n_modes=_number("n_modes", n_modes, 0, True, True), energy=float(energy), inner=inner,
                            velocities=bool(velocities), hyper=hyper, ecsw_tol=_number("ecsw_tol", ecsw_tol, 0),
                            deim_modes=_number("deim_modes", deim_modes, 0, True, True),
                            deim_oversampling=_at_least_one("deim_oversampling", deim_oversampling),
                            hyper_states=_number("hyper_states", hyper_states, 1, True), integrator=integrator,
                            rtol=_number("rtol", rtol, 0), newton_tangent=newton_tangent,
                            max_iterations=_number("max_iterations", max_iterations, 0, True),
                            newton_iterations=_number("newton_iterations", newton_iterations, 0, True, True))

    # ------------------------------------------------------------------ offline
    def build(self, training: Training) -> GalerkinModel:
        o, tic = self.options, time.perf_counter()
        if training.snapshots is None or training.backend is None or training.system is None or training.dt is None:
            raise ValueError("pod_galerkin.build: needs a trajectory training (snapshots, backend, system, dt)")
        be, full = training.backend, training.system
        if training.snapshots.shape[0] != full.n:
            raise ValueError(f"pod_galerkin.build: snapshots have {training.snapshots.shape[0]} rows, the system "
                             f"{full.n} dofs")
        free = np.asarray(full.free)
        pod, projector, info = snapshot_basis(training, free, o)
        V = pod.modes
        timings = {"basis_s": time.perf_counter() - tic}
        tic = time.perf_counter()
        fixed = np.asarray(full.fixed)
        basis_full = np.zeros((full.n, V.shape[1]))
        basis_full[free] = V
        linear = bool(be.problem.material.is_linear)
        forces, info["hyper"] = self._forces(be, full, V, basis_full, free, fixed, projector, training, linear)
        timings["hyper_s"] = time.perf_counter() - tic
        history = training.history if training.history is not None else getattr(scene_of(training, self.name),
                                                                                 "history", None)
        if history is None:
            raise ValueError("pod_galerkin.build: the training has no load history")
        driven = ScaledHistory(history)
        system = reduced_system(full, V, free, forces, be, driven, linear=linear)
        integrator = self._integrator(training)
        lam = training.parameter_values("load_factor") if training.parameters else np.zeros(0)
        envelope = {"load_factor": (float(lam.min()), float(lam.max()))} if lam.size else {}
        info.update(integrator=integrator[0], integrator_options=integrator[1], offline=timings,
                    elements_per_evaluation=int(getattr(forces, "size", 0)), linear_material=linear)
        model = GalerkinModel(V, free, be, system, integrator, driven, projector, envelope, info)
        if training.outputs:
            model.attach_outputs(training.outputs)
        return model

    def _forces(self, be, full, V, basis_full, free, fixed, projector, training, linear):
        o = self.options
        if linear:  # the reduced operator is exact and constant: nothing to sample
            K = be.tangent(np.zeros(full.n))
            K_rc = V.T @ K[free][:, fixed].toarray() if full.has_prescribed else None
            return LinearForces(V.T @ (K[free][:, free] @ V), K_rc), {
                "scheme": "exact", "note": "linear material: the reduced operator is exact and constant"}
        n_cells = be.problem.mesh.n_cells
        exact = element_forces(be, np.arange(n_cells), np.ones(n_cells), basis_full, fixed)
        if o["hyper"] == "none":
            return exact, {"scheme": "none", "elements": n_cells}
        states = training_states(training, free, fixed, projector, full.has_prescribed, o["hyper_states"])
        if o["hyper"] == "ecsw":
            cells, w, info = ecsw_rule(exact, states, o["ecsw_tol"], be.problem.mesh.points, be.problem.mesh.cells)
            return element_forces(be, exact.cells[cells], w, basis_full, fixed), {"scheme": "ecsw", **info}
        full_u = []
        for q, uc in states:
            u = basis_full @ q
            if uc is not None:
                u[fixed] = uc
            full_u.append(u)
        modes = o["deim_modes"] or 2 * V.shape[1]
        deim = deim_forces(be, V, free, basis_full, fixed, full_u, modes, o["deim_oversampling"])
        return deim, {"scheme": "deim", **deim.info}

    def _integrator(self, training) -> tuple[str, dict]:
        """(name, options) of the reduced integrator: the option, else the scene's (its options
        with it), else the training run's; HHT where that is explicit. Newton's options added."""
        o = self.options
        scene = scene_of(training, self.name)
        analysis = getattr(scene, "analysis", None) or {}
        own = analysis.get("integrator") or (training.info or {}).get("integrator")
        own_opts = dict(analysis.get("integrator_options", (training.info or {}).get("options", {})) or {})
        name = o["integrator"] or own or "hht"
        opts = own_opts if name == own else {}
        if not make_integrator(name).implicit:
            name, opts = "hht", {}
        opts = {k: v for k, v in opts.items() if not k.startswith("newton_") and k != "linear_solver"}
        return name, {**opts, "newton_rtol": o["rtol"], "newton_max_iter": o["max_iterations"],
                      "newton_tangent": o["newton_tangent"], "newton_iterations": o["newton_iterations"]}
