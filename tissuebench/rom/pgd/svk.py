"""``"pgd_svk"``: the PGD modes as the Ritz basis of the nonlinear Saint Venant-Kirchhoff
problem at the contact position (pgd-vademecum-cutting §4.1 and §5: the vademecum
modes used "à la POD", srb space).

Offline: the (linear) vademecum of the contact over the accessible surface, an
orthonormal basis Q of span{X_i} (srb space), and the reduced SVK internal force as an
exact cubic ``f_r(q) = L q + Q(q, q) + C(q, q, q)`` (tensors by polarization,
:func:`~tissuebench.rom.polynomial.reduced_polynomial`; homogeneous Dirichlet, dead
loads). Online, ``step({"position": j, "load_factor": lam})`` solves
``f_r(q) = lam Q^T f(s_p)`` by Newton from the linear predictor (N x N, no full-size
vector); if that does not converge, by load increments (2, 4, 8 ...) up to
``max_increments``; still not converged: status ``"failed"`` with the residuals.
"""
from __future__ import annotations

import math

import numpy as np
import scipy.linalg as sla

from ..base import (POLYNOMIAL_MATERIALS, Applies, LinearReconstruction, OnlineModel, RomMethod, StepResult,
                    Training, register)
from ..polynomial import check_polynomial_problem, reduced_polynomial
from .linear import check_pgd_options
from .online import LocatedContact, locate
from .training import family_from_training, scene_of, uncut_backend
from .vademecum import build_vademecum

__all__ = ["PgdSvk", "PgdSvkModel"]


@register
class PgdSvk(RomMethod):
    """Reduced SVK Newton on the srb space of a PGD vademecum.

    Options
    -------
    n_modes, tol, max_fixed_point, fixed_point_tol, seed : of the vademecum
    rtol : float, Newton tolerance on ``|r| / |lam Q^T f|``
    max_iterations : int, Newton iterations per increment
    max_increments : int, largest number of load increments tried (powers of two)
    """

    name = "pgd_svk"
    kind = "map"
    training_kinds = ("operators",)
    applies = Applies(materials=POLYNOMIAL_MATERIALS, dead_loads=True, point_load=True, homogeneous_dirichlet=True,
                      mesh_builders=("cornea_dome",))  # mu: node / accessible-node index, not a Scene.at key

    def __init__(self, n_modes: int = 6, tol: float = 1e-8, max_fixed_point: int = 50, fixed_point_tol: float = 1e-8,
                 seed: int = 0, rtol: float = 1e-10, max_iterations: int = 25, max_increments: int = 16):
        check_pgd_options(self.name, n_modes, tol, max_fixed_point, fixed_point_tol, seed)
        if not (np.isfinite(rtol) and rtol > 0):
            raise ValueError(f"{self.name}: rtol must be > 0, got {rtol!r}")
        for name, v in (("max_iterations", max_iterations), ("max_increments", max_increments)):
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
                raise ValueError(f"{self.name}: {name} must be a positive integer, got {v!r}")
        self.n_modes, self.tol, self.max_fixed_point, self.fixed_point_tol = int(n_modes), tol, max_fixed_point, \
            fixed_point_tol
        self.seed, self.rtol, self.max_iterations, self.max_increments = seed, rtol, max_iterations, max_increments

    def build(self, training: Training) -> OnlineModel:
        scene = scene_of(training, self.name)
        if not scene.is_fe:
            raise ValueError(f"{self.name}: needs a finite-element scene, {scene.name!r} is {scene.model!r}")
        be = uncut_backend(training, scene, self.name)
        check_polynomial_problem(be.problem, self.name)
        fam = family_from_training(Training(backend=be, scene=training.scene, info=training.info), self.name)
        vad = build_vademecum(fam, self.n_modes, self.tol, self.max_fixed_point, self.fixed_point_tol, self.seed)
        Q, _ = np.linalg.qr(vad.X)
        poly = reduced_polynomial(be, Q, fam.free_dofs)
        return PgdSvkModel(self.name, vad, Q, poly, be.problem, self.rtol, self.max_iterations, self.max_increments)


class PgdSvkModel(LocatedContact, LinearReconstruction, OnlineModel):
    """Online reduced SVK Newton (module docstring); ``q`` = coefficients on ``basis`` (Q)."""

    kind = "map"

    def __init__(self, name, vademecum, basis, poly, problem, rtol, max_iterations, max_increments):
        self.name, self.vademecum, self.basis, self.poly = name, vademecum, basis, poly
        fam = vademecum.family
        self.free_dofs, self.ndof, self.problem = fam.free_dofs, fam.ndof, problem
        self.rtol, self.max_iterations, self.max_increments = rtol, max_iterations, max_increments
        self._L_inv = np.linalg.inv(poly.L)
        self._gesv = sla.get_lapack_funcs("gesv", (poly.L,))  # the m x m solve without np.linalg's checks

    @property
    def n_reduced(self) -> int:
        return self.basis.shape[1]

    def contact_nodes(self) -> np.ndarray | None:
        """The surface family's parameter nodes: where the contact is placed."""
        return self.vademecum.family.nodes

    @property
    def envelope(self) -> dict:
        return {"position": (0, self.vademecum.family.n_parameters - 1)}

    @property
    def info(self) -> dict:
        """Record of the offline build (the sweep's ``model_info``)."""
        return {**self.vademecum.build_info(), "svk_force_evaluations": self.poly.n_evals}

    def prescribed(self, mu):  # homogeneous Dirichlet conditions only (checked offline)
        fixed = np.setdiff1d(np.arange(self.ndof), self.free_dofs)
        return fixed, np.zeros(len(fixed))

    def prescribed_affine(self):
        n = self.ndof - len(self.free_dofs)
        return np.zeros(n), np.zeros(n)

    def _newton(self, q, f, scale, norms):
        force_and_tangent, gesv, tol = self.poly.force_and_tangent, self._gesv, self.rtol * scale
        for _ in range(self.max_iterations):
            r, K = force_and_tangent(q)
            r -= f
            norms.append(math.sqrt(r @ r))
            if not math.isfinite(norms[-1]):
                return None
            if norms[-1] <= tol:
                return q
            dq, info = gesv(K, r)[2:]
            if info != 0:
                return None
            q = q - dq
        r = self.poly.force(q) - f
        norms.append(math.sqrt(r @ r))
        return q if norms[-1] <= tol else None

    def step(self, mu) -> StepResult:
        """Reduced SVK equilibrium under the contact force at the position of ``mu``."""
        c, status, msg, lam = locate(self.vademecum, mu, self.name, need_S=False)
        if c is None:
            return StepResult(None, "failed", msg, mu=dict(mu))
        f = np.dot(c.values, self.basis[c.rows])
        if lam != 1.0:
            f *= lam
        scale = max(math.sqrt(f @ f), 1e-300)
        norms: list = []
        n = 1
        while n <= self.max_increments:
            q = self._L_inv @ (f / n)  # linear predictor of the first increment
            for k in range(1, n + 1):
                q = self._newton(q, f * (k / n) if n > 1 else f, scale, norms)
                if q is None:
                    break
            if q is not None:
                info = {"increments": n, "residual_norms": norms, "parameter_index": c.index}
                return StepResult(q, status, msg, info, mu)
            n *= 2
        return StepResult(None, "failed", f"{self.name}: reduced Newton did not converge with up to "
                          f"{self.max_increments} increments (last residual {norms[-1]:.3e}, target "
                          f"{self.rtol * scale:.3e})", info={"residual_norms": norms}, mu=dict(mu))

    def floor_ops(self):
        """The load on the basis rows of a contact, one Newton iteration (the reduced force and
        tangent, the m x m solve) and the output product: a step needs at least one."""
        fam = self.vademecum.family
        rows, vals = fam.load_at(fam.nodes[fam.n_parameters // 2])
        B, q = np.ascontiguousarray(self.basis[rows]), 0.5 * (self._L_inv @ (vals @ self.basis[rows]))
        gesv, poly = self._gesv, self.poly
        C_r = getattr(self, "_outputs", (None, None, None))[2]
        y = np.empty(0 if C_r is None else C_r.shape[0])

        def floor():
            f = vals @ B
            r, K = poly.force_and_tangent(q)
            r -= f
            gesv(K, r)
            if C_r is not None:
                np.dot(C_r, q, out=y)
        return floor
