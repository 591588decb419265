"""``opinf``: operator inference, a learned reduced model of the training trajectories, by OpInf.

OpInf (0.6, https://willcox-research-group.github.io/rom-operator-inference-Python3/) learns a
polynomial reduced model from data alone: no finite-element operator is read, only the trajectories
tissuebench hands it (displacements, velocities, times, the load factor).

* The basis: ``opinf.basis.PODBasis`` of the displacement snapshots (free dofs); the reduced state
  ``x = [q / s, q' t / s]`` (``q = V^T u``, ``q' = V^T v``; ``s`` the largest ``|q|``, ``t`` the ratio of
  the displacements' and velocities' norms: both halves of order one, for the least squares).
* The model: ``time = "discrete"`` an ``opinf.models.DiscreteModel`` ``x_{k+1} = A x_k +
  H (x_k (x) x_k) + B [lam_k, lam_{k+1}]`` (the loads at both ends of the step: an implicit scheme's
  step reads both) at the training's snapshot spacing, one evaluation per haptic step
  (it steps only at that spacing: another ``dt`` is refused at ``start``, naming both);
  ``time = "continuous"`` (default) an ``opinf.models.ContinuousModel`` ``x' = A x + H (x (x) x) + B lam(t)``
  fitted on ``x'`` (``q'`` from the velocities, ``q''`` by OpInf's ``ddt_uniform``), stepped by OpInf's
  ``predict`` (SciPy's ``solve_ivp``) over each step, at any ``dt``. ``operators`` is OpInf's own
  operator string (``"AHB"``: linear, quadratic, input).
* The regularisation: OpInf's ``ROM.fit_regselect_discrete`` / ``fit_regselect_continuous`` chooses the
  weight of its ``L2Solver`` (Tikhonov, one scalar) among ``regularizers`` candidates (then refines
  it): the least training error among the models that stay stable over the training runs.

A step is ``"extrapolation"`` where its load factor lies outside the training runs'; a non-finite state
fails the step and ends the run.
"""
from __future__ import annotations

import time

import numpy as np
from tissuebench.rom import Applies, LinearReconstruction, OnlineModel, RomMethod, StepResult, Training, \
    check_parameters

from ._common import envelope_of, fraction, missing, positive_int, status_at, step_start

__all__ = ["OpInf"]

TIME = ("discrete", "continuous")


class OpInf(RomMethod):
    """Operator inference of the training trajectories (module docstring).

    Options
    -------
    n_modes : int or None
        POD modes of the displacements (None: OpInf's ``cumulative_energy = energy``).
    energy : float in (0, 1]
        The energy criterion when ``n_modes`` is None.
    operators : str
        OpInf's operator string (``"AHB"``; ``"cAHB"`` adds a constant, ``"AB"`` a linear model).
    time : {"discrete", "continuous"}
        A fully discrete model at the snapshot spacing, or a time-continuous one (module docstring).
    regularizers : int
        How many Tikhonov weights (log-spaced over 1e-12 .. 1e4) OpInf's selection starts from.
    """

    name = "opinf"
    kind = "trajectory"
    training_kinds = ("trajectory",)
    applies = Applies(homogeneous_dirichlet=True)
    counterpart = ("pod_galerkin", {"hyper": "ecsw"})

    def __init__(self, n_modes=None, energy=0.99999, operators="AHB", time="continuous", regularizers=17):
        who = "opinf"
        if time not in TIME:
            raise ValueError(f"{who} option time = {time!r}; valid: {list(TIME)}")
        if not isinstance(operators, str) or not operators or set(operators) - set("cAHGB"):
            raise ValueError(f"{who} option operators = {operators!r}: OpInf's letters c, A, H, G, B (e.g. 'AHB')")
        self.options = dict(n_modes=positive_int(who, "n_modes", n_modes, True), energy=fraction(who, "energy", energy),
                            operators=operators, time=time,
                            regularizers=positive_int(who, "regularizers", regularizers))

    @classmethod
    def unavailable(cls) -> str:
        return missing("opinf")

    def build(self, training: Training) -> OnlineModel:
        if training.snapshots is None or training.parameters is None or training.free_dofs is None:
            raise ValueError("opinf.build: needs trajectory snapshots with their times and load factors")
        import opinf

        o, tic = self.options, time.perf_counter()
        free = np.asarray(training.free_dofs)
        S = training.snapshots
        basis = opinf.basis.PODBasis(num_vectors=o["n_modes"]) if o["n_modes"] else \
            opinf.basis.PODBasis(cumulative_energy=o["energy"])
        basis.fit(S[free])
        V = np.asarray(basis.entries)
        runs = _runs(training)
        times = training.parameter_values("time")
        lams = training.parameter_values("load_factor")
        Q = V.T @ S[free]
        if training.velocities is not None:
            Qd = V.T @ np.asarray(training.velocities)[free]
        else:  # OpInf's finite differences, run by run
            Qd = np.zeros_like(Q)
            for cols in runs:
                Qd[:, cols] = opinf.ddt.ddt_uniform(Q[:, cols], float(np.diff(times[cols]).mean()), order=2)
        s = max(float(np.abs(Q).max()), 1e-300)
        tau = float(np.linalg.norm(Q) / max(np.linalg.norm(Qd), 1e-300))
        X = np.vstack([Q / s, Qd * (tau / s)])
        spacing = np.concatenate([np.diff(times[cols]) for cols in runs])
        delta = float(np.median(spacing))
        if not np.allclose(spacing, delta, rtol=1e-6):
            raise ValueError(f"opinf.build: the snapshots are not evenly spaced in time ({spacing.min():.6g} .. "
                             f"{spacing.max():.6g} s)")
        candidates = list(np.logspace(-12, 4, o["regularizers"]))
        model_cls = opinf.models.DiscreteModel if o["time"] == "discrete" else opinf.models.ContinuousModel
        rom = opinf.roms.ROM(model_cls(o["operators"], solver=opinf.lstsq.L2Solver(regularizer=1.0)))
        states = [X[:, cols] for cols in runs]
        fit = time.perf_counter()
        with np.errstate(all="ignore"):  # unstable candidates overflow on purpose: OpInf discards them
            if o["time"] == "discrete":
                # the map x_k -> x_{k+1} reads the loads at the step's start and end (the harness's mu: its end)
                inputs = [np.vstack([lams[cols], np.append(lams[cols][1:], lams[cols][-1])]) for cols in runs]
                rom.fit_regselect_discrete(candidates, states, inputs if "B" in o["operators"] else None)
            else:
                ddts = []
                for cols in runs:
                    acc = opinf.ddt.ddt_uniform(Qd[:, cols], delta, order=2)
                    ddts.append(np.vstack([Qd[:, cols] / s, acc * (tau / s)]))
                funcs = [_input_function(times[cols], lams[cols]) for cols in runs]
                rom.fit_regselect_continuous(candidates, [times[cols] for cols in runs], states, ddts,
                                             funcs if "B" in o["operators"] else None)
        info = {"library": "opinf", "n_modes": int(V.shape[1]), "state_dimension": int(X.shape[0]),
                "operators": o["operators"], "time": o["time"], "snapshot_spacing_s": delta, "runs": len(runs),
                "regularizer": _regularizer(rom.model), "fit_s": time.perf_counter() - fit,
                "offline_s": time.perf_counter() - tic}
        model = _OpInfModel(self.name, rom.model, V, s, tau, delta, training, envelope_of(training), o, info)
        if training.outputs:
            model.attach_outputs(training.outputs)
        return model


def _runs(training) -> list:
    """The snapshot columns of each training run, in time order."""
    ids = training.trajectories if training.trajectories is not None else np.zeros(training.snapshots.shape[1])
    times = training.parameter_values("time")
    out = []
    for run in np.unique(ids):
        cols = np.flatnonzero(ids == run)
        out.append(cols[np.argsort(times[cols], kind="stable")])
    return out


def _input_function(times, lams):
    def lam(t):
        return np.array([np.interp(t, times, lams)])
    return lam


def _regularizer(model) -> float:
    reg = getattr(getattr(model, "solver", None), "regularizer", None)
    try:
        return float(np.max(reg))
    except (TypeError, ValueError):
        return float("nan")


class _OpInfModel(LinearReconstruction, OnlineModel):
    """One step of the learned model per call (module docstring)."""

    kind = "trajectory"

    def __init__(self, name, model, V, s, tau, delta, training, envelope, options, info):
        self.name, self._model, self._s, self._tau, self._delta = name, model, s, tau, delta
        r = V.shape[1]
        self.r, self._V = r, V
        self.basis = np.hstack([V * s, np.zeros_like(V)])  # u_free = s V x[:r]
        self.free_dofs, self.ndof = np.asarray(training.free_dofs), training.snapshots.shape[0]
        self.problem = getattr(training.backend, "problem", None)
        self._discrete = options["time"] == "discrete"
        self._envelope, self.info = dict(envelope), info
        self._x = self._t = self._lam = self._dt = self._stopped = None

    @property
    def n_reduced(self) -> int:
        return 2 * self.r

    @property
    def envelope(self) -> dict:
        return dict(self._envelope)

    def start(self, mu0=None, state0=None, dt=None) -> None:
        """Project ``state0`` (``{"u", "v"}``; default rest); steps of ``dt`` (the snapshot spacing when discrete)."""
        if dt is None or not dt > 0:
            raise ValueError(f"{self.name}.start: a trajectory model needs the time step dt > 0, got {dt!r}")
        if self._discrete and abs(dt - self._delta) > 1e-6 * self._delta:
            raise ValueError(f"{self.name}.start: dt = {dt!r}: the discrete model steps at the training's snapshot "
                             f"spacing {self._delta!r} s only (time = 'continuous' steps at any dt)")
        x = np.zeros(2 * self.r)
        for k, (key, factor) in enumerate((("u", 1.0 / self._s), ("v", self._tau / self._s))):
            value = (state0 or {}).get(key)
            if value is not None:
                value = np.asarray(value, float)
                if value.shape != (self.ndof,):
                    raise ValueError(f"{self.name}.start: state0[{key!r}] has shape {value.shape}, expected "
                                     f"({self.ndof},)")
                x[k * self.r:(k + 1) * self.r] = factor * (self._V.T @ value[self.free_dofs])
        lam0 = float((mu0 or {}).get("load_factor", 0.0))
        self._x, self._t, self._lam, self._dt, self._stopped = x, None, lam0, float(dt), None

    def step(self, mu) -> StepResult:
        mu = check_parameters(mu, ("time", "load_factor"), self.name)
        t, lam = float(mu["time"]), float(mu["load_factor"])
        out = {"time": t, "load_factor": lam}
        if self._x is None:
            raise RuntimeError(f"{self.name}: call start(mu0, state0, dt) before step()")
        if self._stopped is not None:
            return StepResult(None, "failed", self._stopped, mu=out)
        t0 = step_start(self.name, t, self._t, self._dt)
        with np.errstate(all="ignore"):
            if self._discrete:
                x = self._model.rhs(self._x, np.array([self._lam, lam]))
            else:
                lam0 = self._lam

                def load(s):
                    return np.array([lam0 + (s - t0) / self._dt * (lam - lam0)])
                x = self._model.predict(self._x, np.array([t0, t]), load)[:, -1]
        if x.shape != self._x.shape or not np.all(np.isfinite(x)):
            self._stopped = f"{self.name}: the learned model left the finite numbers at t = {t:.6g}"
            return StepResult(None, "failed", self._stopped, mu=out)
        self._x, self._t, self._lam = x, t, lam
        status, message = status_at(self.name, lam, self._envelope)
        return StepResult(x.copy(), status, message, mu=out)

    def floor_ops(self):
        """The discrete model's one evaluation (the step's arithmetic); the default reduced solve otherwise."""
        if not self._discrete:
            return super().floor_ops()
        x, lam = np.zeros(2 * self.r), np.array([0.5, 0.5])
        model = self._model
        return lambda: model.rhs(x, lam)
