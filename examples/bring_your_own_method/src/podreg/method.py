"""POD + polynomial regression of the reduced coordinates in the load factor.

Offline: the POD basis of the path's snapshots on the free dofs (the SVD's leading ``n_modes``
left singular vectors), each snapshot's reduced coordinates ``q_j = B^T u_j[free]``, and a
least-squares polynomial of degree ``degree`` per coordinate in the scaled load factor
``x = lambda / lambda_max`` without a constant term: the path starts at rest (``u = 0`` at load
factor 0), which the model then reproduces exactly (with a constant term the fit misses rest by
a fixed offset, which tissuebench's evaluation near rest finds as a relative error of tens of
per cent). Online: ``q(lambda) = sum_{k=1..degree} c_k x^k`` (a ``degree x n_modes`` product),
the field ``u[free] = B q`` and the prescribed values of the step on the fixed dofs
(tissuebench's :class:`~tissuebench.rom.LinearReconstruction`). Outside rest to the training's
largest load factor the step is flagged ``extrapolation``: a polynomial is not to be trusted there.
"""
from __future__ import annotations

import numpy as np

from tissuebench.rom import (Applies, LinearReconstruction, OnlineModel, RomMethod, StepResult, Training,
                             check_parameters)


def _count(name: str, value, least: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < least:
        raise ValueError(f"pod_polyreg: {name} = {value!r}; expected an integer >= {least}")
    return int(value)


class PodPolyReg(RomMethod):
    """POD with polynomial regression (module docstring).

    Parameters
    ----------
    n_modes : int
        POD modes kept (fewer when the snapshots span fewer).
    degree : int
        Degree of the polynomial of each reduced coordinate in the load factor, >= 1 (at most
        the number of distinct nonzero training load factors).
    """

    name = "pod_polyreg"
    kind = "map"
    training_kinds = ("path",)
    applies = Applies()  # any finite-element scene with a static load path; its step reads the load factor

    def __init__(self, n_modes: int = 4, degree: int = 2):
        self.n_modes, self.degree = _count("n_modes", n_modes, 1), _count("degree", degree, 1)

    def build(self, training: Training) -> OnlineModel:
        free = np.asarray(training.free_dofs)
        lams = training.parameter_values("load_factor")
        if len(np.unique(lams[lams != 0])) < self.degree:
            raise ValueError(f"pod_polyreg: degree = {self.degree} needs {self.degree} distinct nonzero load factors; "
                             f"the training has {len(np.unique(lams[lams != 0]))}")
        U, s, _ = np.linalg.svd(training.snapshots[free], full_matrices=False)
        rank = int(np.sum(s > 1e-12 * s[0])) if s.size and s[0] > 0 else 0
        r = max(1, min(self.n_modes, rank))
        basis = np.ascontiguousarray(U[:, :r])
        coords = basis.T @ training.snapshots[free]  # (r, n_snap)
        top = float(np.abs(lams).max()) or 1.0
        V = np.vander(lams / top, self.degree + 1, increasing=True)[:, 1:]  # no constant term: rest is u = 0
        coeffs = np.linalg.lstsq(V, coords.T, rcond=None)[0]  # (degree, r)
        energy = float(np.sum(s[:r] ** 2) / np.sum(s ** 2)) if rank else 1.0
        problem = training.backend.problem if training.backend is not None else None
        return _PodPolyRegModel(basis, free, training.snapshots.shape[0], problem, coeffs, top,
                                (min(0.0, float(lams.min())), float(lams.max())),
                                {"n_modes": r, "degree": self.degree, "energy_captured": energy})


class _PodPolyRegModel(LinearReconstruction, OnlineModel):
    kind = "map"

    def __init__(self, basis, free_dofs, ndof, problem, coeffs, top, envelope, info):
        self.name, self.basis, self.free_dofs, self.ndof, self.problem = "pod_polyreg", basis, free_dofs, ndof, problem
        self._coeffs, self._top, self._envelope, self.info = coeffs, top, envelope, info
        self._powers = np.arange(1, coeffs.shape[0] + 1)

    @property
    def n_reduced(self) -> int:
        return self.basis.shape[1]

    @property
    def envelope(self) -> dict:
        return {"load_factor": self._envelope}

    def step(self, mu) -> StepResult:
        mu = check_parameters(mu, ("load_factor",), self.name)
        lam = mu["load_factor"]
        q = (lam / self._top) ** self._powers @ self._coeffs  # a new array each step: it belongs to the result
        lo, hi = self._envelope
        if lo - 1e-12 <= lam <= hi + 1e-12:
            return StepResult(q, mu=mu)
        return StepResult(q, "extrapolation", f"load_factor = {lam:g} is outside the training's [{lo:g}, {hi:g}]: "
                          "the regression polynomial is extrapolated", mu=mu)

    def floor_ops(self):
        """What a step cannot avoid: the polynomial's powers, their product with the coefficients,
        and the output product."""
        C_r = getattr(self, "_outputs", (None, None, None))[2]
        x = 0.5

        def floor():
            q = x ** self._powers @ self._coeffs
            if C_r is not None:
                np.dot(C_r, q)

        return floor
