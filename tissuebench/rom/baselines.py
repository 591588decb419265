"""Baselines every study carries, so a method's worth is visible.

* ``"nearest"``: the stored snapshot whose parameters are nearest to ``mu`` (parameters
  scaled by their training range), returned as is. What a look-up table of precomputed
  states gives for free. Trained on trajectories, a snapshot's parameters are its time and
  its load factor: the state stored at the nearest (time, load) of the training runs, a
  recording played back (its load factor alone would map every released or unloaded instant
  onto the rest state at time 0: 100 % off after a probe's release, every step ok).
* ``"pod_interp"``: non-intrusive POD. The snapshots' POD coefficients ``a_j = Phi^T u_j``
  are interpolated over the parameters (``interpolation="linear"``: piecewise linear,
  ``np.interp`` in 1D and Delaunay ``LinearNDInterpolator`` beyond; ``"rbf"``:
  ``scipy.interpolate.RBFInterpolator``), no equation is solved online.

Both read ``training.snapshots`` with ``training.parameters`` (every numeric key but
``time``, which ``nearest`` reads on trajectories; e.g. ``load_factor``, or ``position`` and
``load_factor``), and flag a ``mu`` outside the training envelope as ``"extrapolation"``
(linear: the nearest snapshot's coefficients are used there; rbf: its own extrapolation; a
time past the training runs' horizon).
"""
from __future__ import annotations

import numpy as np
from scipy.interpolate import LinearNDInterpolator, RBFInterpolator

from .base import (Applies, DeferredStepResult, LinearReconstruction, OnlineModel, RomMethod, StepResult, Training,
                   register)
from .interpolants import Linear1D, LinearSimplex, RbfAtPoint
from .online import parameter
from .pod import pod_basis
from .reads import training_kind

__all__ = ["Nearest", "PodInterp"]


def _parameter_table(training: Training, who: str, time: bool = False):
    """(keys, P (n_snap, d), lo (d,), span (d,)) of the training parameters (``time`` among them
    when asked)."""
    if training.snapshots is None or not training.parameters:
        raise ValueError(f"{who}: training needs snapshots and their parameters")
    keys = sorted(k for k, v in training.parameters[0].items()
                  if (time or k != "time") and isinstance(v, (int, float)) and not isinstance(v, bool))
    if not keys:
        raise ValueError(f"{who}: the training parameters have no numeric key (got {training.parameters[0]})")
    P = np.column_stack([training.parameter_values(k) for k in keys])
    lo, hi = P.min(axis=0), P.max(axis=0)
    return keys, P, lo, np.where(hi > lo, hi - lo, 1.0)


class _ParametricModel(OnlineModel):
    kind = "map"

    def __init__(self, name, keys, P, lo, span):
        self.name, self.keys, self._lo, self._span = name, keys, lo, span
        self._X = (P - lo) / span  # scaled training parameters
        self._hi = lo + np.where(P.max(axis=0) > P.min(axis=0), span, 0.0)
        # the haptic path, per key: (key, lo, span, lower and upper bound of "inside") as floats
        self._bounds = [(k, float(a), float(s), float(a - 1e-12 * (1 + abs(a))), float(b + 1e-12 * (1 + abs(b))))
                        for k, a, s, b in zip(keys, lo, span, self._hi)]
        self._x = np.empty(len(keys))

    @property
    def envelope(self) -> dict:
        return {k: (float(a), float(b)) for k, a, b in zip(self.keys, self._lo, self._hi)}

    def step_parameters(self) -> tuple:
        """The keys of the training's parameters: the step looks them all up."""
        return tuple(self.keys) + super().step_parameters()

    def _scaled(self, mu):
        """(scaled parameters (d,), inside the envelope, the parameters read): one float per key,
        no copy of ``mu`` (:func:`~.online.parameter`)."""
        x, inside, name = self._x, True, self.name
        for i, (k, a, s, lo, hi) in enumerate(self._bounds):
            v = parameter(mu, k, name)
            if not lo <= v <= hi:
                inside = False
            x[i] = (v - a) / s
        return x, inside

    def _outside(self, q, info, mu) -> DeferredStepResult:
        """The ``extrapolation`` result, its message formatted when read."""
        values = {k: float(mu[k]) for k in self.keys}
        return DeferredStepResult(q, "extrapolation", lambda: f"mu = {values} outside the training envelope "
                                  f"{self.envelope}", info, mu)


@register
class Nearest(RomMethod):
    """The stored snapshot nearest to ``mu`` (no options); on trajectories, nearest in time and load."""

    name = "nearest"
    kind = "map"
    training_kinds = ("path", "positions", "trajectory")
    # reads the numeric parameters of its training snapshots: the position when trained on positions
    applies = Applies(models=("fe", "poisson1d", "frame2dof", "hermite_beam"), parameters={"positions": ("position",)})

    def build(self, training: Training) -> OnlineModel:
        # on trajectories a state belongs to its time as much as to its load (module docstring)
        in_time = training_kind(training) == "trajectory"
        keys, P, lo, span = _parameter_table(training, self.name, time=in_time)
        if in_time and "time" not in keys:
            raise ValueError(f"{self.name}: a trajectory training needs the time of every snapshot "
                             f"(training.parameters[0] = {training.parameters[0]})")
        problem = getattr(getattr(training, "backend", None), "problem", None)
        return _NearestModel(self.name, keys, P, lo, span, training.snapshots, problem)


class _NearestModel(_ParametricModel):
    def __init__(self, name, keys, P, lo, span, S, problem=None):
        super().__init__(name, keys, P, lo, span)
        self._S = S
        # the step's prescribed (Dirichlet) values replace the stored snapshot's on the fixed dofs:
        # the prescribed motion is an input the haptic loop knows (the ROM contract's full field)
        fixed = getattr(problem, "fixed_dofs", None)
        self._problem = problem if fixed is not None and len(fixed) and S.shape[0] == problem.ndof else None
        self._D = np.empty_like(self._X)  # squared differences to the stored parameters
        self._d2 = np.empty(len(self._X))
        self._ones = np.ones(self._X.shape[1])  # their row sums as one matrix-vector product

    @property
    def n_reduced(self) -> int:
        return 1

    def _nearest(self, x) -> int:
        """Index of the stored parameters nearest to ``x``: ``argmin sum((X - x)^2)`` on
        preallocated arrays (the first of equals, as ``np.argmin``); the row sums as a product with
        ones (half the time of ``np.sum(axis=1)`` at these sizes)."""
        D = np.subtract(self._X, x, out=self._D)
        np.square(D, out=D)
        if D.shape[1] == 1:
            return int(D[:, 0].argmin())
        return int(np.dot(D, self._ones, out=self._d2).argmin())

    def step(self, mu) -> StepResult:
        x, inside = self._scaled(mu)
        j = self._nearest(x)
        if inside:
            return StepResult(np.array([float(j)]), "ok", "", {"snapshot": j}, mu)
        return self._outside(np.array([float(j)]), {"snapshot": j}, mu)

    def floor_ops(self):
        """The distances to the stored parameters, their argmin, the stored outputs of that snapshot."""
        x = self._X.mean(axis=0)
        Y = getattr(self, "_outputs", ((), np.zeros((0, len(self._X)))))[1]

        def floor():
            Y[:, self._nearest(x)]
        return floor

    def attach_outputs(self, operators) -> None:
        names = list(operators)
        C = np.array([operators[n] for n in names]).reshape(len(names), -1)
        self._outputs = (names, C @ self._S)
        # outputs that read prescribed dofs follow the step's values there, as reconstruct does
        pb = self._problem
        Cf = C[:, pb.fixed_dofs] if pb is not None else np.zeros((len(names), 0))
        self._fixed_outputs = (Cf, self._S[pb.fixed_dofs]) if np.any(Cf) else None

    def outputs(self, result) -> dict:
        names, Y = getattr(self, "_outputs", ((), None))
        if not names or result.q is None:
            return {n: float("nan") for n in names}
        j, y = int(result.q[0]), Y[:, int(result.q[0])]
        fixed, mu = getattr(self, "_fixed_outputs", None), result.mu
        if fixed is not None and mu is not None and "load_factor" in mu:
            Cf, Sf = fixed
            y = y + Cf @ (self._problem.prescribed_values(float(mu["load_factor"])) - Sf[:, j])
        return dict(zip(names, y.tolist()))

    def reconstruct(self, result) -> np.ndarray:
        if result.q is None:
            raise ValueError(f"{self.name}: cannot reconstruct a failed step ({result.message})")
        u = self._S[:, int(result.q[0])].copy()
        pb, mu = self._problem, result.mu
        if pb is not None and mu is not None and "load_factor" in mu:
            u[pb.fixed_dofs] = pb.prescribed_values(float(mu["load_factor"]))
        return u


@register
class PodInterp(RomMethod):
    """Non-intrusive POD with interpolated coefficients.

    Parameters
    ----------
    n_modes : int, optional
        POD modes (default: the energy criterion).
    energy : float
        Energy fraction of the criterion when ``n_modes`` is not given.
    interpolation : {"linear", "rbf"}
    kernel : str
        RBF kernel of :class:`scipy.interpolate.RBFInterpolator` (``"rbf"`` only).
    """

    name = "pod_interp"
    kind = "map"
    training_kinds = ("path", "positions")
    applies = Applies(models=("fe", "poisson1d", "frame2dof", "hermite_beam"), parameters={"positions": ("position",)})

    def __init__(self, n_modes: int | None = None, energy: float = 0.999, interpolation: str = "linear",
                 kernel: str = "thin_plate_spline"):
        if interpolation not in ("linear", "rbf"):
            raise ValueError(f"pod_interp: interpolation = {interpolation!r}; valid: ['linear', 'rbf']")
        if n_modes is not None and (isinstance(n_modes, bool) or int(n_modes) != n_modes or n_modes < 1):
            raise ValueError(f"pod_interp: n_modes must be a positive integer, got {n_modes!r}")
        self.n_modes, self.energy, self.interpolation, self.kernel = n_modes, energy, interpolation, kernel

    def build(self, training: Training) -> OnlineModel:
        keys, P, lo, span = _parameter_table(training, self.name)
        pod = pod_basis(training.snapshots, self.energy, self.n_modes)
        coeffs = pod.modes.T @ training.snapshots  # (m, n_snap)
        P, coeffs = _unique_points(P, coeffs.T, keys)
        model = _PodInterpModel(self.name, keys, P, lo, span, pod, coeffs, self)
        model.info = {"n_modes": pod.n_modes, "pod_message": pod.message, "energy_captured": pod.energy_captured}
        return model


def _unique_points(P, A, keys):
    """Training parameters without repeats (an interpolant needs distinct points); a repeated
    parameter with different snapshots is ambiguous: ValueError naming it."""
    U, first, inverse = np.unique(P, axis=0, return_index=True, return_inverse=True)
    if len(U) == len(P):
        return P, A
    scale = max(float(np.abs(A).max()), 1e-300)
    for j in range(len(U)):
        rows = A[inverse.ravel() == j]
        if np.abs(rows - rows[0]).max() > 1e-10 * scale:
            raise ValueError(f"pod_interp: parameters {dict(zip(keys, U[j].tolist()))} appear {len(rows)} times "
                             "with different snapshots")
    return P[first], A[first]


class _PodInterpModel(LinearReconstruction, _ParametricModel):
    def __init__(self, name, keys, P, lo, span, pod, A, options):
        _ParametricModel.__init__(self, name, keys, P, lo, span)
        self.basis, self.ndof = pod.modes, pod.modes.shape[0]
        self.free_dofs = np.arange(self.ndof)
        self._A = A  # (n_snap, m) coefficients at the training parameters
        X = self._X
        self._always_finite = False
        if options.interpolation == "rbf":
            self._f = RbfAtPoint(RBFInterpolator(X, A, kernel=options.kernel))
        elif X.shape[1] == 1:
            order = np.argsort(X[:, 0], kind="stable")
            self._f = Linear1D(X[order, 0], A[order])
            self._always_finite = bool(np.all(np.isfinite(A)))  # blends and end values of finite data
        else:
            self._f = LinearSimplex(LinearNDInterpolator(X, A).tri, A)
        self._nearest_model = _NearestModel(name, keys, P, lo, span, np.zeros((1, len(P))))

    @property
    def n_reduced(self) -> int:
        return self.basis.shape[1]

    def step(self, mu) -> StepResult:
        x, inside = self._scaled(mu)
        q = self._f(x)
        if q is None or not (self._always_finite or np.isfinite(q).all()):
            # outside the Delaunay hull: the nearest snapshot's coefficients
            q = self._A[self._nearest_model._nearest(x)].copy()
            inside = False
        if inside:
            return StepResult(q, "ok", "", {}, mu)
        return self._outside(q, {}, mu)

    def floor_ops(self):
        """The interpolant's arithmetic at one point (:mod:`.interpolants`) and the output product."""
        x = self._X.mean(axis=0)
        blend = self._f.floor(x)
        C_r = getattr(self, "_outputs", (None, None, None))[2]
        if C_r is None:
            return blend
        q, y = np.ones(C_r.shape[1]), np.empty(C_r.shape[0])

        def floor():
            blend()
            np.dot(C_r, q, out=y)
        return floor
