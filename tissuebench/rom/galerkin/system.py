"""The Galerkin projection of a semi-discrete system, as a system the integrators march.

A :class:`ReducedSystem` is a :class:`~tissuebench.refsolvers.dynamics.SecondOrderSystem`
whose free unknowns are the reduced coordinates ``q`` (``u_f = V q``, ``V`` the basis of the
free dofs) and whose fixed unknowns are the full model's prescribed dofs ``u_c``, so HHT,
Newmark, Bathe and backward Euler step it with their own update formulas, prescribed motion
included, without a line of them written again::

    M_r = [[V^T M_ff V, V^T M_fc], [M_cf V, M_cc]]    f_int,r(q) = V^T f_int(V q, u_c)
    f_ext,r(t) = V^T (f_0 + lam(t) f_1)              K_t,r(q) = V^T K_ff(V q, u_c) V

The reduced force and tangent come from a :class:`~.forces.ReducedForces` (full assembly
over every element, or an ECSW or DEIM sample). The rows of the prescribed dofs (the support
reaction that :func:`~tissuebench.refsolvers.dynamics.integrate` books as work on a prescribed
motion) and the tangent at rest (Rayleigh damping) are assembled in full: they are read once
per run, never in a step. The free blocks are dense arrays (``q`` is small): the Newton
matrix of a step is then a dense ``r x r`` array, solved by LAPACK.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ...refsolvers.dynamics import SecondOrderSystem

__all__ = ["ReducedSystem", "reduced_system"]


class ReducedSystem(SecondOrderSystem):
    """See the module docstring; build it with :func:`reduced_system`."""

    def __post_init__(self):
        super().__post_init__()
        # cached_property values are instance attributes: the free blocks become dense arrays
        self.M_ff = np.asarray(sp.csr_matrix(self.M_ff).toarray())

    def bind(self, forces, basis_full, backend, f0, f1, history, prescribed_order):
        """Attach what the reduced operators need (:func:`reduced_system`)."""
        self.forces, self.basis_full, self.backend = forces, basis_full, backend
        self.f0, self.f1, self.history, self._order = f0, f1, history, prescribed_order
        #: the full model's fixed dofs in the order of the reduced system's fixed unknowns (sorted)
        self.full_fixed = backend.problem.fixed_dofs[prescribed_order]
        self.r = basis_full.shape[1]
        if self.damped:
            self.C_ff = np.asarray(self.alpha_m * self.M_ff + self.beta_k * self.K0_ff.toarray())
        return self

    # ------------------------------------------------------------------ the step's operators
    def _uc(self, u_c):
        return u_c if self.has_prescribed else None

    def f_int(self, u_f, u_c=None):
        return self.forces.force(u_f, self._uc(u_c))

    def K_t(self, u_f, t=None, u_c=None):
        return self.forces.tangent(u_f, self._uc(u_c))

    def f_ext(self, t, u_f, u_c=None):
        return self.f0 + float(self.history(t)) * self.f1

    def energy(self, u_f, u_c=None):
        return self.forces.energy(u_f, self._uc(u_c))

    # ------------------------------------------------------------------ full vectors (bookkeeping)
    def _full_u(self, x):
        x = np.asarray(x, float)
        u = self.basis_full @ x[:self.r]
        if self.has_prescribed:
            u[self.full_fixed] = x[self.r:]
        return u

    def _reduce_rows(self, f_full):
        """``[V^T f_free; f_fixed]`` of a full-dof vector (the reduced unknowns' rows)."""
        out = self.basis_full.T @ f_full
        if not self.has_prescribed:
            return out
        return np.concatenate([out, f_full[self.full_fixed]])

    def full_internal_force(self, x):
        """``internal_force`` of the reduced unknowns by full assembly (support reactions)."""
        return self._reduce_rows(self.backend.internal_force(self._full_u(x)))

    def full_tangent(self, x):
        """``tangent`` of the reduced unknowns by full assembly (the tangent at rest: damping)."""
        K = self.backend.tangent(self._full_u(x))
        E = self._extension()
        return sp.csr_matrix(E.T @ (K @ E))

    def _extension(self):
        """The map of the reduced unknowns to the full dofs, (ndof, r + n_c)."""
        V = sp.csr_matrix(self.basis_full)
        if not self.has_prescribed:
            return V
        fixed = self.full_fixed
        P = sp.csr_matrix((np.ones(len(fixed)), (fixed, np.arange(len(fixed)))), shape=(V.shape[0], len(fixed)))
        return sp.hstack([V, P]).tocsr()


def reduced_system(full: SecondOrderSystem, basis, free, forces, backend, history, linear=False) -> ReducedSystem:
    """The Galerkin projection of ``full`` on ``basis`` (module docstring).

    Parameters
    ----------
    full : SecondOrderSystem
        The full model's system (mass, Rayleigh coefficients, which dofs are free).
    basis : (n_free, r) array
        The reduced basis of the free dofs ``free`` (the full system's, sorted).
    forces : ReducedForces
        Reduced internal force, tangent and energy.
    backend : Backend
        The full operators (loads, prescribed values, the bookkeeping rows).
    history : callable
        Load factor versus time (the driven one: :class:`~..fe_baselines.stepping.ScaledHistory`).
    linear : bool
        A linear material: the integrators factorise the step matrix once.

    Raises
    ------
    ValueError
        The loads depend on the displacement (follower loads), or are not affine in the load factor.
    """
    pb = backend.problem
    n = full.n
    u0 = np.zeros(n)
    if backend.external_tangent(u0, 1.0) is not None:
        raise ValueError("pod_galerkin: follower loads depend on the displacement; needs dead loads")
    ext = [backend.external_force(u0, lam)[free] for lam in (0.0, 0.5, 1.0)]
    if not np.allclose(ext[1], 0.5 * (ext[0] + ext[2]), rtol=1e-12, atol=1e-12 * max(np.abs(ext[2]).max(), 1e-300)):
        raise ValueError("pod_galerkin: the loads are not affine in the load factor")
    V = np.ascontiguousarray(basis)
    basis_full = np.zeros((n, V.shape[1]))
    basis_full[free] = V
    f0, f1 = V.T @ ext[0], V.T @ (ext[2] - ext[0])
    has_motion = full.has_prescribed
    order = np.argsort(pb.fixed_dofs)
    M_ff = V.T @ (full.M_ff @ V)
    if has_motion:
        M_fc = V.T @ full.M_fc.toarray()
        M_cc = sp.csr_matrix(full.M)[full.fixed][:, full.fixed]
        M = sp.bmat([[sp.csr_matrix(M_ff), sp.csr_matrix(M_fc)], [sp.csr_matrix(M_fc.T), M_cc]]).tocsr()

        def prescribed(t):
            return np.asarray(pb.prescribed_values(float(history(t))), float)[order]
    else:
        M, prescribed = sp.csr_matrix(M_ff), None
    r = V.shape[1]
    holder = {}

    def internal_force(x):
        return holder["system"].full_internal_force(x)

    def tangent(x):
        return holder["system"].full_tangent(x)

    system = ReducedSystem(M=M, internal_force=internal_force, tangent=tangent, load=lambda t: np.zeros(M.shape[0]),
                           free=np.arange(r), alpha_m=full.alpha_m, beta_k=full.beta_k, linear=bool(linear),
                           strain_energy=None, prescribed=prescribed)
    holder["system"] = system
    return system.bind(forces, basis_full, backend, f0, f1, history, order)
