"""The offline PGD vademecum ``u(x, s) ≈ sum_i X_i(x) S_i(s)`` of a moving point load
(pgd-vademecum-cutting §2, Appendix A), built by :func:`~tissuebench.rom.separated_solver.pgd_solve`
on the operators of a :class:`~.family.PointLoadFamily` (``A = K ⊗ W``, the point loads
in separated form): no snapshot of a full solve is computed.

For this single-term operator the greedy rank-one Galerkin problem is the minimisation
of the energy norm ``|u - u_n|_{K ⊗ W}``, so the fixed point converges to the leading
singular pair of ``K^{1/2} U W^{1/2}`` (U the matrix of all solutions) and the modes are
those of a weighted SVD, found without forming U.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from ..separated import SeparatedOperator, SeparatedSolution, SeparatedVector
from ..separated_solver import pgd_solve
from .family import PointLoadFamily
from .floor import rank_floor

__all__ = ["Vademecum", "build_vademecum"]


@dataclass(eq=False)
class Vademecum:
    """Separated solution of a point-load family.

    Attributes
    ----------
    family : PointLoadFamily
    X : (n_free, N) space modes on the free dofs
    S : (n_s, N) parameter modes at the parameter nodes
    record : SeparatedSolution (fixed-point iterations, convergence, amplitudes,
        residuals and stop reason of the build)
    """

    family: PointLoadFamily
    X: np.ndarray
    S: np.ndarray
    record: SeparatedSolution

    @property
    def n_modes(self) -> int:
        return self.X.shape[1]

    @property
    def gamma(self) -> np.ndarray:
        """``int_S S_i ds`` (N,) (paper eq. 15, nodal quadrature)."""
        return self.family.weights @ self.S

    @property
    def alpha(self) -> np.ndarray:
        """``int_S S_i S_j ds`` (N, N); its diagonal is the alpha of eq. 15."""
        return self.S.T @ (self.family.weights[:, None] * self.S)

    def truncated(self, n: int) -> "Vademecum":
        """The first ``n`` modes (nested when built without ``update_last``)."""
        return Vademecum(self.family, self.X[:, :n], self.S[:, :n], self.record.truncated(n))

    def parameter_weights(self, position) -> tuple[np.ndarray, np.ndarray] | None:
        """(parameter-node indices, interpolation weights) of ``position`` in the
        vademecum's parameter domain, or None outside it (line: a coordinate, linear
        interpolation of S between nodes; surface: a mesh node id that is a parameter node)."""
        fam = self.family
        if fam.kind == "line":
            s = fam.coords
            p = float(position)
            if not s[0] - 1e-12 * (s[-1] - s[0]) <= p <= s[-1] + 1e-12 * (s[-1] - s[0]):
                return None
            k = int(np.clip(np.searchsorted(s, p) - 1, 0, len(s) - 2))
            t = (p - s[k]) / (s[k + 1] - s[k])
            return np.array([k, k + 1]), np.array([1.0 - t, t])
        j = fam.parameter_of_node(int(position))
        return (np.array([j]), np.ones(1)) if j >= 0 else None

    def S_at(self, position) -> np.ndarray | None:
        """``S_i(position)`` (N,), None outside the parameter domain."""
        pw = self.parameter_weights(position)
        return None if pw is None else pw[1] @ self.S[pw[0]]

    def field(self, position) -> np.ndarray:
        """Vademecum evaluation ``sum_i X_i S_i(s)`` on the free dofs (n_free,)."""
        S = self.S_at(position)
        if S is None:
            raise ValueError(f"position {position!r} is outside the vademecum's parameter domain")
        return self.X @ S

    @functools.cached_property
    def rank_floor(self) -> dict:
        """The least error of any space of ``n_modes`` modes on this family (:mod:`.floor`)."""
        return rank_floor(self.family, self.n_modes)

    def build_info(self) -> dict:
        """JSON-able record of the build (modes, fixed-point iterations, stop reason ...,
        and the rank floor of the family at this number of modes)."""
        r = self.record
        return {"n_modes": self.n_modes, "fixed_point_iterations": list(r.fixed_point_iterations),
                "fixed_point_converged": list(r.converged), "amplitudes": list(r.amplitudes),
                "residuals": list(r.residuals), "stop_reason": r.stop_reason, "message": r.message,
                "n_parameters": self.family.n_parameters, "n_free": self.family.n_free,
                "operators": "stiffness K (free dofs) ⊗ parameter weights W; point loads f(s_j) ⊗ w_j e_j",
                "rank_floor": self.rank_floor}


def build_vademecum(family: PointLoadFamily, n_modes: int = 10, tol: float = 1e-8, max_fixed_point: int = 50,
                    fixed_point_tol: float = 1e-8, seed: int = 0, update_last: bool = False,
                    patience: int | None = None) -> Vademecum:
    """PGD vademecum of ``family`` (options of :func:`~tissuebench.rom.separated_solver.pgd_solve`).

    The stagnation stop is off by default (``patience=None``): the Euclidean residual of a
    moving point load decreases by less than 0.1 % per mode on a large parameter set (1673
    anterior nodes of the paper cornea: the build stopped at 6 modes) while every mode
    still reduces the energy error; the amplitude criterion ``tol`` and ``n_modes`` stop it.

    Returns
    -------
    Vademecum
        ``X`` are the space factors (unit Euclidean norm), ``S`` carry the amplitudes.
    """
    W = sp.diags(family.weights, format="csr")
    A = SeparatedOperator([(family.K, W)])
    f = SeparatedVector.from_columns([family.loads, W.tocsc()])
    sol = pgd_solve(A, f, max_modes=n_modes, tol=tol, max_fixed_point=max_fixed_point,
                    fixed_point_tol=fixed_point_tol, rng=seed, update_last=update_last,
                    patience=patience)
    if sol.n_modes == 0:
        raise ValueError(f"build_vademecum: no mode could be computed ({sol.message})")
    return Vademecum(family, sol.mode_matrix(0), sol.mode_matrix(1), sol)
