"""``pymor_galerkin``: POD-Galerkin with empirical interpolation of the internal force, by pyMOR.

Every step of the reduction is pyMOR's own (pyMOR 2026.1, https://pymor.org):

* the basis: ``pymor.algorithms.pod.pod`` of the training's displacement snapshots (free dofs);
* the full model: the finite-element internal force as a pyMOR ``Operator`` (``apply`` and
  ``jacobian`` by the backend's assembly, ``restricted`` from the elements around a set of dofs:
  :mod:`._pymor_ops`), the loads as a ``LincombOperator`` of the load factor;
* the hyper-reduction (``hyper = "deim"``): ``pymor.algorithms.ei.deim`` on force snapshots, an
  ``EmpiricalInterpolatedOperator``; ``hyper = "none"``: the projected operator (every element);
* the projection: ``StationaryRBReductor`` on static paths, ``pymor.algorithms.projection.project``
  of the force, mass and damping on trajectories;
* online: pyMOR's ``NewtonSolver`` (``apply_inverse``, warm-started from the last state) on a static
  path, pyMOR's ``ImplicitEulerTimeStepper`` (the stepper pyMOR has for a nonlinear operator; its
  implicit midpoint rule refuses one) on the first-order form ``x = [q, q']`` of a trajectory, one
  step per call.

The force snapshots of DEIM: on trajectories, the internal force at (at most ``hyper_states``) training
states, evenly through the runs: projected on the basis (``force_states = "projected"``, the states
``pod_galerkin`` fits its DEIM on: the pair then differs by the library only), or the snapshots
themselves (``"snapshots"``, as pyMOR's ``interpolate_operators`` evaluates an operator at solution
snapshots; on the neo-Hookean liver its reduced Newton then fails within 0.06 s). On a static path that
is degenerate: at an equilibrium ``f_int = lam f_ext`` (dead loads), so every snapshot is a multiple of
the load (and zero where only a support moves), a collateral basis of rank one. The forces are also
taken at the iterates of pyMOR's reduced Newton solves (``NewtonSolver(return_stages=True)``, every
element, from rest to each training load factor): the states a reduced Newton passes through online.
"""
from __future__ import annotations

import time

import numpy as np
from tissuebench.rom import Applies, LinearReconstruction, OnlineModel, RomMethod, StepResult, Training, \
    check_parameters

from ._common import (envelope_of, evenly, fraction, is_dynamic, missing, moving_supports, positive, positive_int,
                      status_at, step_start)

__all__ = ["PymorGalerkin"]

HYPER = ("deim", "none")
FORCE_STATES = ("projected", "snapshots")


class PymorGalerkin(RomMethod):
    """POD-Galerkin with DEIM by pyMOR (module docstring).

    Options
    -------
    n_modes : int or None
        Basis size (None: the smallest with ``energy`` of the snapshots: pyMOR's ``l2_err``).
    energy : float in (0, 1]
        The energy criterion when ``n_modes`` is None.
    hyper : {"deim", "none"}
        pyMOR's empirical interpolation of the internal force, or the projected operator (every element).
    deim_modes : int or None
        Collateral basis size (None: twice the basis size, as ``pod_galerkin``).
    hyper_states : int
        At most this many training states give the force snapshots of a trajectory.
    force_states : {"projected", "snapshots"}
        The trajectory states the force snapshots are taken at: projected on the basis, or as stored.
    rtol : float
        pyMOR ``NewtonSolver``'s relative tolerance.
    max_iterations : int
        pyMOR ``NewtonSolver``'s iterations per solve.
    """

    name = "pymor_galerkin"
    kind = "path"
    training_kinds = ("path", "trajectory")
    applies = Applies(dead_loads=True)
    counterpart = {"path": ("pod_newton", {}), "trajectory": ("pod_galerkin", {})}

    def __init__(self, n_modes=None, energy=0.99999, hyper="deim", deim_modes=None, hyper_states=60,
                 force_states="projected", rtol=1e-7, max_iterations=25):
        who = "pymor_galerkin"
        for name, value, valid in (("hyper", hyper, HYPER), ("force_states", force_states, FORCE_STATES)):
            if value not in valid:
                raise ValueError(f"{who} option {name} = {value!r}; valid: {list(valid)}")
        self.options = dict(n_modes=positive_int(who, "n_modes", n_modes, True), energy=fraction(who, "energy", energy),
                            hyper=hyper, deim_modes=positive_int(who, "deim_modes", deim_modes, True),
                            hyper_states=positive_int(who, "hyper_states", hyper_states), force_states=force_states,
                            rtol=positive(who, "rtol", rtol), max_iterations=positive_int(who, "max_iterations",
                                                                                         max_iterations))

    @classmethod
    def unavailable(cls) -> str:
        return missing("pymor")

    @classmethod
    def why_not(cls, scene, options=None) -> str:
        why = super().why_not(scene, options)
        if not why and is_dynamic(scene) and moving_supports(scene):
            return ("pyMOR's time stepper marches the first-order form with fixed supports here; a [[dirichlet]] entry "
                    "prescribes a displacement")
        return why

    # ------------------------------------------------------------------ offline
    def build(self, training: Training) -> OnlineModel:
        if training.snapshots is None or training.backend is None:
            raise ValueError("pymor_galerkin.build: needs snapshots and a finite-element backend")
        from pymor.algorithms.pod import pod
        from pymor.core.logger import set_log_levels
        from pymor.vectorarrays.numpy import NumpyVectorSpace

        from ._pymor_ops import InternalForce

        set_log_levels({"pymor": "WARN"})  # pyMOR logs every Newton iteration at INFO: a sweep's output is its own

        o, tic = self.options, time.perf_counter()
        free = np.asarray(training.free_dofs)
        op = InternalForce(training)
        U = op.source.make_array(training.snapshots[free])
        l2 = 0.0 if o["n_modes"] else float(np.sqrt(1.0 - o["energy"]) * np.linalg.norm(training.snapshots[free]))
        RB, svals = pod(U, modes=o["n_modes"], l2_err=l2)
        info = {"n_modes": len(RB), "library": "pymor", "basis_s": time.perf_counter() - tic,
                "singular_values": [float(s) for s in svals[:60]]}
        f0, f1 = _affine_loads(training, free)
        space = NumpyVectorSpace(len(free))
        if training.dt is not None and training.system is not None:
            return self._trajectory(training, op, RB, space, f0, f1, info)
        return self._path(training, op, RB, space, f0, f1, info)

    def _interpolated(self, op, RB, forces, info):
        """pyMOR's DEIM of ``forces`` and the interpolated operator (``hyper = "none"``: ``op``)."""
        if self.options["hyper"] == "none":
            info["hyper"] = {"scheme": "none", "elements": int(op.backend.problem.mesh.n_cells)}
            return op
        from pymor.algorithms.ei import deim
        from pymor.operators.ei import EmpiricalInterpolatedOperator

        tic = time.perf_counter()
        dofs, collateral, data = deim(forces, modes=self.options["deim_modes"] or 2 * len(RB))
        eio = EmpiricalInterpolatedOperator(op, dofs, collateral, triangular=False)
        info["hyper"] = {"scheme": "deim", "interpolation_dofs": int(len(dofs)), "force_snapshots": len(forces),
                         "elements": int(len(eio.restricted_operator.kernel.cells)),
                         "source_dofs": int(len(eio.source_dofs)), "offline_s": time.perf_counter() - tic}
        return eio

    def _path(self, training, op, RB, space, f0, f1, info):
        from pymor.algorithms.projection import project
        from pymor.models.basic import StationaryModel
        from pymor.operators.constructions import LincombOperator, VectorOperator
        from pymor.parameters.functionals import ProjectionParameterFunctional
        from pymor.reductors.basic import StationaryRBReductor

        o = self.options
        rhs = LincombOperator([VectorOperator(space.make_array(f0[:, None])), VectorOperator(space.make_array(
            f1[:, None]))], [1.0, ProjectionParameterFunctional("load_factor")])
        forces = None
        if o["hyper"] == "deim":
            tic = time.perf_counter()
            forces = _apply_each(op, training)
            stages = _newton_stages(project(op, RB, RB), project(rhs, RB, None), training, o)
            for lam, q in stages:
                forces.append(op.apply(RB.lincomb(q), mu=_mu(lam)))
            info["stages_s"] = time.perf_counter() - tic
            info["newton_stages"] = int(sum(q.shape[1] for _, q in stages))
        fom = StationaryModel(self._interpolated(op, RB, forces, info), rhs, name="fe")
        rom = StationaryRBReductor(fom, RB).reduce()
        model = _PathModel(self.name, rom, RB.to_numpy(), training, envelope_of(training), o, info)
        if training.outputs:
            model.attach_outputs(training.outputs)
        return model

    def _trajectory(self, training, op, RB, space, f0, f1, info):
        from pymor.algorithms.projection import project
        from pymor.operators.constructions import LincombOperator, VectorOperator
        from pymor.operators.numpy import NumpyMatrixOperator
        from pymor.parameters.functionals import ProjectionParameterFunctional

        o, system = self.options, training.system
        free = np.asarray(training.free_dofs)
        if not np.array_equal(np.asarray(system.free), free) or system.has_prescribed:
            raise ValueError("pymor_galerkin.build: a trajectory with a prescribed motion (the first-order form here "
                             "holds the supports fixed)")
        forces = None
        if o["hyper"] == "deim":
            states = op.source.make_array(training.snapshots[free][:, evenly(training.snapshots.shape[1],
                                                                             o["hyper_states"])])
            if o["force_states"] == "projected":  # pyMOR's orthogonal projection on the basis
                states = RB.lincomb(RB.inner(states))
            forces = op.apply(states)
        f_r = project(self._interpolated(op, RB, forces, info), RB, RB)
        M_r = project(NumpyMatrixOperator(system.M_ff), RB, RB).matrix
        C_r = project(NumpyMatrixOperator(system.C_ff), RB, RB).matrix if system.C_ff is not None else \
            np.zeros_like(M_r)
        r = len(RB)
        zero = np.zeros(r)
        load = [project(VectorOperator(space.make_array(f[:, None])), RB, None).as_range_array().to_numpy()[:, 0]
                for f in (f0, f1)]
        from pymor.vectorarrays.numpy import NumpyVectorSpace

        X = NumpyVectorSpace(2 * r)
        F = LincombOperator([VectorOperator(X.make_array(np.concatenate([zero, load[0]])[:, None])),
                             VectorOperator(X.make_array(np.concatenate([zero, load[1]])[:, None]))],
                            [1.0, ProjectionParameterFunctional("load_factor")])
        mass = NumpyMatrixOperator(np.block([[np.eye(r), np.zeros((r, r))], [np.zeros((r, r)), np.asarray(M_r)]]))
        model = _TrajectoryModel(self.name, f_r, np.asarray(C_r), mass, F, RB.to_numpy(), training,
                                 envelope_of(training), o, info)
        if training.outputs:
            model.attach_outputs(training.outputs)
        return model


def _mu(lam: float):
    from pymor.parameters.base import Mu

    return Mu({"load_factor": np.array([float(lam)])})


def _apply_each(op, training):
    """The internal force at every training snapshot, each at its own load factor (a moving support)."""
    free = np.asarray(training.free_dofs)
    lams = training.parameter_values("load_factor")
    out = op.range.empty()
    for j, lam in enumerate(lams):
        out.append(op.apply(op.source.make_array(training.snapshots[free, j][:, None]), mu=_mu(lam)))
    return out


def _affine_loads(training, free):
    """``(f0, f1)``: the loads on the free dofs at load factor 0 and their increment per unit factor."""
    be = training.backend
    u0 = np.zeros(be.ndof)
    ext = [be.external_force(u0, lam)[free] for lam in (0.0, 0.5, 1.0)]
    scale = max(float(np.abs(ext[2]).max()), 1e-300)
    if be.external_tangent(u0, 1.0) is not None or not np.allclose(ext[1], 0.5 * (ext[0] + ext[2]), rtol=1e-12,
                                                                    atol=1e-12 * scale):
        raise ValueError("pymor_galerkin.build: the loads must be dead and affine in the load factor")
    return ext[0], ext[2] - ext[0]


def _newton_stages(op_r, rhs_r, training, options) -> list:
    """The iterates of pyMOR's reduced Newton solves (every element) from rest to each training load
    factor, ``[(load factor, reduced coordinates (r, k))]``: the non-equilibrium states DEIM's force
    snapshots need (module docstring)."""
    from pymor.core.exceptions import NewtonError
    from pymor.solvers.newton import NewtonSolver

    solver = NewtonSolver(rtol=options["rtol"], maxiter=options["max_iterations"], return_stages=True)
    out = []
    for lam in np.unique(training.parameter_values("load_factor")):
        if lam == 0.0:
            continue
        mu = _mu(lam)
        try:
            _, info = op_r.apply_inverse(rhs_r.as_vector(mu), mu=mu, solver=solver, return_info=True)
        except NewtonError:
            continue  # a load factor the projected model does not reach from rest: its snapshot still counts
        stages = info.get("stages") if isinstance(info, dict) else None
        if stages is not None and len(stages):
            out.append((float(lam), stages.to_numpy()))
    return out


class _PymorModel(LinearReconstruction, OnlineModel):
    def __init__(self, name, basis, training, envelope, options, info):
        self.name, self.basis = name, np.ascontiguousarray(basis)
        self.free_dofs, self.ndof = np.asarray(training.free_dofs), training.snapshots.shape[0]
        self.problem = training.backend.problem
        self._envelope, self.info = dict(envelope), info
        from pymor.solvers.newton import NewtonSolver

        self._solver = NewtonSolver(rtol=options["rtol"], maxiter=options["max_iterations"])

    @property
    def envelope(self) -> dict:
        return dict(self._envelope)


class _PathModel(_PymorModel):
    """A static path: pyMOR's Newton on the reduced model, from the last converged state."""

    kind = "path"

    def __init__(self, name, rom, basis, training, envelope, options, info):
        super().__init__(name, basis, training, envelope, options, info)
        self._op, self._rhs = rom.operator, rom.rhs
        self.start()

    @property
    def n_reduced(self) -> int:
        return self.basis.shape[1]

    def start(self, mu0=None, state0=None, dt=None) -> None:
        """Forget the warm start (the next solve starts from rest)."""
        self._q = None

    def step(self, mu) -> StepResult:
        from pymor.core.exceptions import InversionError, NewtonError

        lam = float(check_parameters(mu, ("load_factor",), self.name)["load_factor"])
        p = _mu(lam)
        try:
            q = self._op.apply_inverse(self._rhs.as_vector(p), mu=p, initial_guess=self._q, solver=self._solver)
        except (NewtonError, InversionError) as exc:
            return StepResult(None, "failed", f"{self.name}: pyMOR's Newton at load factor {lam:g}: {exc}",
                              mu={"load_factor": lam})
        values = q.to_numpy()[:, 0]
        if not np.all(np.isfinite(values)):
            return StepResult(None, "failed", f"{self.name}: a non-finite state at load factor {lam:g}",
                              mu={"load_factor": lam})
        self._q = q
        status, message = status_at(self.name, lam, self._envelope)
        return StepResult(values.copy(), status, message, mu={"load_factor": lam})


class _TrajectoryModel(_PymorModel):
    """A trajectory: one step of pyMOR's implicit Euler on ``x = [q, q']`` per call."""

    kind = "trajectory"

    def __init__(self, name, f_r, C_r, mass, F, basis, training, envelope, options, info):
        super().__init__(name, basis, training, envelope, options, info)
        from pymor.algorithms.timestepping import ImplicitEulerTimeStepper

        from ._pymor_ops import FirstOrderForm

        self.r = basis.shape[1]
        # the reconstruction reads q, the first half of the state [q, q']
        self.basis = np.hstack([self.basis, np.zeros_like(self.basis)])
        self._A, self._M, self._F = FirstOrderForm(f_r, C_r), mass, F
        self._stepper = ImplicitEulerTimeStepper(1, solver=self._solver)
        self._projector = np.linalg.pinv(basis)
        self._x = self._t = self._dt = self._stopped = None

    @property
    def n_reduced(self) -> int:
        return 2 * self.r

    def start(self, mu0=None, state0=None, dt=None) -> None:
        """Project ``state0`` (``{"u", "v"}`` on every dof; default rest); steps of ``dt``."""
        if dt is None or not dt > 0:
            raise ValueError(f"{self.name}.start: a trajectory model needs the time step dt > 0, got {dt!r}")
        x = np.zeros(2 * self.r)
        for k, key in enumerate(("u", "v")):
            value = (state0 or {}).get(key)
            if value is not None:
                value = np.asarray(value, float)
                if value.shape != (self.ndof,):
                    raise ValueError(f"{self.name}.start: state0[{key!r}] has shape {value.shape}, expected "
                                     f"({self.ndof},)")
                x[k * self.r:(k + 1) * self.r] = self._projector @ value[self.free_dofs]
        self._x, self._t, self._dt, self._stopped = self._A.source.make_array(x[:, None]), None, float(dt), None

    def step(self, mu) -> StepResult:
        mu = check_parameters(mu, ("time", "load_factor"), self.name)
        t, lam = float(mu["time"]), float(mu["load_factor"])
        out = {"time": t, "load_factor": lam}
        if self._x is None:
            raise RuntimeError(f"{self.name}: call start(mu0, state0, dt) before step()")
        if self._stopped is not None:
            return StepResult(None, "failed", self._stopped, mu=out)
        t0 = step_start(self.name, t, self._t, self._dt)
        try:
            steps = self._stepper.iterate(t0, t, self._x, self._A, rhs=self._F, mass=self._M, mu=_mu(lam))
            next(steps)  # the initial state
            x, _ = next(steps)
        except Exception as exc:  # noqa: BLE001 - pyMOR's Newton (NewtonError, InversionError, LinAlgError)
            self._stopped = f"{self.name}: pyMOR's implicit Euler stopped at t = {t:.6g}: {type(exc).__name__}: {exc}"
            return StepResult(None, "failed", self._stopped, mu=out)
        values = x.to_numpy()[:, 0]
        if not np.all(np.isfinite(values)):
            self._stopped = f"{self.name}: a non-finite state at t = {t:.6g}"
            return StepResult(None, "failed", self._stopped, mu=out)
        self._x, self._t = x, t
        status, message = status_at(self.name, lam, self._envelope)
        return StepResult(values.copy(), status, message, mu=out)
