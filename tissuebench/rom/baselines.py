"""Baselines every study carries, so a method's worth is visible.

* ``"nearest"``: the stored snapshot whose parameters are nearest to ``mu`` (parameters
  scaled by their training range), returned as is. What a look-up table of precomputed
  states gives for free.
* ``"pod_interp"``: non-intrusive POD. The snapshots' POD coefficients ``a_j = Phi^T u_j``
  are interpolated over the parameters (``interpolation="linear"``: piecewise linear,
  ``np.interp`` in 1D and Delaunay ``LinearNDInterpolator`` beyond; ``"rbf"``:
  ``scipy.interpolate.RBFInterpolator``), no equation is solved online.

Both read ``training.snapshots`` with ``training.parameters`` (every numeric key but
``time``; e.g. ``load_factor``, or ``position`` and ``load_factor``), and flag a ``mu``
outside the training envelope as ``"extrapolation"`` (linear: the nearest snapshot's
coefficients are used there; rbf: its own extrapolation).
"""
from __future__ import annotations

import numpy as np
from scipy.interpolate import LinearNDInterpolator, RBFInterpolator

from .base import LinearReconstruction, OnlineModel, RomMethod, StepResult, Training, check_parameters, register
from .pod import pod_basis

__all__ = ["Nearest", "PodInterp"]


def _parameter_table(training: Training, who: str):
    """(keys, P (n_snap, d), lo (d,), span (d,)) of the training parameters."""
    if training.snapshots is None or not training.parameters:
        raise ValueError(f"{who}: training needs snapshots and their parameters")
    keys = sorted(k for k, v in training.parameters[0].items() if k != "time" and isinstance(v, (int, float)))
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

    @property
    def envelope(self) -> dict:
        return {k: (float(a), float(b)) for k, a, b in zip(self.keys, self._lo, self._hi)}

    def _scaled(self, mu):
        mu = check_parameters(mu, tuple(self.keys), self.name)
        p = np.array([float(mu[k]) for k in self.keys])
        inside = bool(np.all(p >= self._lo - 1e-12 * (1 + abs(self._lo))) and
                      np.all(p <= self._hi + 1e-12 * (1 + abs(self._hi))))
        return (p - self._lo) / self._span, inside, {k: float(mu[k]) for k in self.keys}


@register
class Nearest(RomMethod):
    """The stored snapshot nearest to ``mu`` (no options)."""

    name = "nearest"
    kind = "map"
    training_kinds = ("path", "positions", "trajectory")

    def build(self, training: Training) -> OnlineModel:
        keys, P, lo, span = _parameter_table(training, self.name)
        return _NearestModel(self.name, keys, P, lo, span, training.snapshots)


class _NearestModel(_ParametricModel):
    def __init__(self, name, keys, P, lo, span, S):
        super().__init__(name, keys, P, lo, span)
        self._S = S

    @property
    def n_reduced(self) -> int:
        return 1

    def step(self, mu) -> StepResult:
        x, inside, mu = self._scaled(mu)
        j = int(np.argmin(np.sum((self._X - x) ** 2, axis=1)))
        status = "ok" if inside else "extrapolation"
        msg = "" if inside else f"mu = {mu} outside the training envelope {self.envelope}"
        return StepResult(np.array([float(j)]), status, msg, {"snapshot": j}, mu=mu)

    def attach_outputs(self, operators) -> None:
        names = list(operators)
        self._outputs = (names, np.array([operators[n] for n in names]) @ self._S)

    def outputs(self, result) -> dict:
        names, Y = getattr(self, "_outputs", ((), None))
        if not names or result.q is None:
            return {n: float("nan") for n in names}
        return dict(zip(names, Y[:, int(result.q[0])].tolist()))

    def reconstruct(self, result) -> np.ndarray:
        if result.q is None:
            raise ValueError(f"{self.name}: cannot reconstruct a failed step ({result.message})")
        return self._S[:, int(result.q[0])].copy()


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
    nested = ("n_modes",)
    training_kinds = ("path", "positions")

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
        model = _PodInterpModel(self.name, keys, P, lo, span, pod, coeffs.T, self)
        model.info = {"n_modes": pod.n_modes, "pod_message": pod.message, "energy_captured": pod.energy_captured}
        return model


class _PodInterpModel(LinearReconstruction, _ParametricModel):
    def __init__(self, name, keys, P, lo, span, pod, A, options):
        _ParametricModel.__init__(self, name, keys, P, lo, span)
        self.basis, self.ndof = pod.modes, pod.modes.shape[0]
        self.free_dofs = np.arange(self.ndof)
        self._A = A  # (n_snap, m) coefficients at the training parameters
        X = self._X
        if options.interpolation == "rbf":
            self._f = RBFInterpolator(X, A, kernel=options.kernel)
        elif X.shape[1] == 1:
            order = np.argsort(X[:, 0], kind="stable")
            xs, As = X[order, 0], A[order]
            self._f = lambda x: np.array([[np.interp(x[0, 0], xs, As[:, i]) for i in range(As.shape[1])]])
        else:
            self._f = LinearNDInterpolator(X, A)

    @property
    def n_reduced(self) -> int:
        return self.basis.shape[1]

    def step(self, mu) -> StepResult:
        x, inside, mu = self._scaled(mu)
        q = np.asarray(self._f(x[None, :]), float).reshape(-1)
        if not np.all(np.isfinite(q)):  # outside the Delaunay hull: the nearest snapshot's coefficients
            q = self._A[int(np.argmin(np.sum((self._X - x) ** 2, axis=1)))].copy()
            inside = False
        status = "ok" if inside else "extrapolation"
        msg = "" if inside else f"mu = {mu} outside the training envelope {self.envelope}"
        return StepResult(q, status, msg, mu=mu)
