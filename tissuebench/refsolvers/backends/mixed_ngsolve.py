"""Taylor-Hood forms of the mixed u-p formulation, written symbolically for NGSolve.

The Lagrangian density (per reference volume) is

    L(u, p) = W(F) - (1 - w) U(J) + p (J - 1) - p^2 / (2 kappa)     (w: ``penalty_weight``)

with U the volumetric part of the material (:meth:`Material.volumetric`), p a continuous
P1 field and u the P2 displacement of the :class:`~.ngsolve_backend.NgsolveBackend` it
extends (same mesh, quadrature, fibre field, numbering map). The last term is present
only with a finite ``bulk_modulus`` (perturbed Lagrangian: eliminating p gives back
W - U + kappa/2 (J - 1)^2); without it J = 1 is imposed weakly (incompressible).

The volumetric parts are written here again, symbolically, not taken from the NumPy
kernels, so the scikit-fem forms (:mod:`.mixed_skfem`) are an independent implementation.
Vectors and matrices are returned in tissuebench numbering, unknowns ordered
``z = [u (3 n_nodes), p (n_vertices)]``.
"""
from __future__ import annotations

import contextlib

import ngsolve as ngs
import numpy as np
import scipy.sparse as sp

from ..materials import Guccione, MooneyRivlin, NeoHookean, NeoHookeanDecoupled
from ..solver_base import SparsityPattern, canonical_csr
from .ngsolve_backend import energy_cf


def volumetric_cf(material, J):
    """U(J) of ``material`` as a CoefficientFunction (see :meth:`Material.volumetric`)."""
    if isinstance(material, (Guccione, MooneyRivlin)):
        return 0.5 * material.kappa * (J - 1) ** 2
    if isinstance(material, NeoHookeanDecoupled):
        return 0.25 * material.bulk_modulus * (J ** 2 - 1 - 2 * ngs.log(J))
    if isinstance(material, NeoHookean):
        return 0.5 * material.lame[0] * ngs.log(J) ** 2
    raise TypeError(f"material {material.name!r} has no volumetric part for an incompressible formulation")


class NgsolveMixedForms:
    """f = [f_u; g] and its Jacobian for an :class:`NgsolveBackend` ``be`` (P2 only).

    Parameters
    ----------
    be : NgsolveBackend
    bulk_modulus : float or None
        None: incompressible; a number: perturbed Lagrangian with that modulus.
    penalty_weight : float
        Fraction w of U kept in the density (see :class:`~tissuebench.refsolvers.mixed.MixedBackend`).
    """

    def __init__(self, be, bulk_modulus=None, penalty_weight=0.0):
        self.be = be
        mesh = be.ngmesh
        fes_p = ngs.H1(mesh, order=1)
        self.space = ngs.FESpace([be.fes, fes_p])
        n_u, n_ng_u = be.ndof, be.fes.ndof
        self.n_u, self.n_p = n_u, mesh.nv
        pdof = np.array([fes_p.GetDofNrs(ngs.NodeId(ngs.VERTEX, v))[0] for v in range(mesh.nv)], dtype=np.int64)
        # T maps tissuebench z to NGSolve coefficients: displacement block of the backend,
        # pressure block a permutation (vertex v -> its H1 dof)
        cols, vals = be._Tcols, be._Tvals
        rows = np.repeat(np.arange(len(cols)), cols.shape[1])
        Tu = sp.csr_matrix((vals.ravel(), (rows, cols.ravel())), shape=(n_ng_u, n_u))
        Tp = sp.csr_matrix((np.ones(mesh.nv), (pdof, np.arange(mesh.nv))), shape=(fes_p.ndof, mesh.nv))
        self.T = sp.block_diag((Tu, Tp), format="csr")
        self.Tt = self.T.T.tocsr()
        self.gf = ngs.GridFunction(self.space)
        self._structure = None  # SparsityPattern of the tangent, from the first one
        u, p = self.space.TrialFunction()
        F = ngs.Id(3) + ngs.Grad(u)
        J = ngs.Det(F)
        mat = be.problem.material
        dens = energy_cf(mat, F, be._fibre) + p * (J - 1)
        if penalty_weight != 1.0:
            dens = dens - (1.0 - float(penalty_weight)) * volumetric_cf(mat, J)
        if bulk_modulus is not None:
            dens = dens - p * p / (2.0 * float(bulk_modulus))
        self.form = ngs.BilinearForm(self.space, symmetric=True)
        self.form += ngs.Variation(dens.Compile() * be._dx)

    def _set(self, z):
        self.gf.vec.FV().NumPy()[:] = self.T @ z
        return self.gf.vec

    def _tm(self):
        return contextlib.nullcontext() if self.be._threads == 1 else ngs.TaskManager()

    def force(self, z):
        """[f_u; g] = d/dz of the integral of L, shape (n_u + n_p,)."""
        vec = self._set(z)
        r = vec.CreateVector()
        with self._tm():
            self.form.Apply(vec, r)
        return self.Tt @ r.FV().NumPy()

    def force_and_tangent(self, z):
        """Force and its Jacobian (symmetric, indefinite), CSR (n_u + n_p)^2."""
        return self.force(z), self.tangent(z)

    def tangent(self, z):
        """The Jacobian alone (Newton has the force of this state already), CSR on a fixed
        pattern: the structural one of ``T^T K_ng T`` (SciPy's product drops the entries that
        come out exactly zero, which differ from one state to the next; a direct solver that
        keeps its factorisation needs the same pattern every time)."""
        vec = self._set(z)
        with self._tm():
            self.form.AssembleLinearization(vec)
        vals, cols, ptr = (np.asarray(a) for a in self.form.mat.CSR())
        shape = (self.form.mat.height, self.form.mat.width)
        K = canonical_csr(self.Tt @ sp.csr_matrix((vals.copy(), cols.copy(), ptr.copy()), shape=shape) @ self.T)
        if self._structure is None:
            ones, absT = sp.csr_matrix((np.ones(len(cols)), cols.copy(), ptr.copy()), shape=shape), abs(self.T)
            self._structure = SparsityPattern()
            self._structure.store(canonical_csr(absT.T @ ones @ absT))
        embedded = self._structure.embed(K)
        return K if embedded is None else embedded

    def lagrangian(self, z):
        """Integral of L over the reference volume."""
        vec = self._set(z)
        with self._tm():
            return float(self.form.Energy(vec))
