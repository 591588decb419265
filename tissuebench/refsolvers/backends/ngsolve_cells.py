"""Element quantities of a subset of cells from the NGSolve backend (see ``Backend.cell_kernel``)."""
from __future__ import annotations

import ngsolve as ngs
import numpy as np
import scipy.sparse as sp

from .base import CellKernel
from .ngsolve_mesh import make_intrules

__all__ = ["NgsolveCellKernel"]


class NgsolveCellKernel(CellKernel):
    """Element operators of a subset of cells from NGSolve's symbolic energy.

    The energy is integrated on the discontinuous copy of the space, ``dx`` restricted
    to the subset (``definedonelements``), so each element block is independent: element
    force vectors come from ``Apply``, element tangents are the diagonal blocks of
    ``AssembleLinearization``, energies from an order-0 L2 test function. Element blocks
    are mapped to tissuebench local dofs by ``T_e`` (NGSolve dof j of cell e <- local
    dofs, weights of the backend's dof map), ``f = T_e^T f_ng``, ``K = T_e^T K_ng T_e``.
    Independent of the NumPy material kernels (cross-checked against the scikit-fem kernel).
    """

    def __init__(self, backend, cells):
        from pyngcore import BitArray

        self.cells = cells
        self.dofs = backend.element_dofs()[cells]
        self._unique, self._pos = np.unique(cells, return_inverse=True)
        gf, _, cd, dd, flat, w = backend._dc
        fes_dc = gf.space
        self._gf, self._dd = gf, dd[self._unique]
        mloc = self.dofs.shape[1]
        loc = flat[self._unique] % mloc  # (u, m_dc, r) local tissuebench dof of each term
        T = np.zeros((len(self._unique), dd.shape[1], mloc))
        e = np.arange(len(self._unique))[:, None, None]
        j = np.arange(dd.shape[1])[None, :, None]
        np.add.at(T, (np.broadcast_to(e, loc.shape), np.broadcast_to(j, loc.shape), loc), w[self._unique])
        self._T = T
        ba = BitArray(backend.ngmesh.ne)
        ba.Clear()
        for c in self._unique:
            ba.Set(int(c))
        dx = ngs.dx(intrules=make_intrules(backend.problem.element, backend._order), definedonelements=ba)
        energy = backend._energy(fes_dc.TrialFunction())
        self._form = ngs.BilinearForm(fes_dc, symmetric=True)
        self._form += ngs.Variation(energy * dx)
        l2 = ngs.L2(backend.ngmesh, order=0)
        self._efun = ngs.LinearForm(backend._energy(gf) * l2.TestFunction() * dx)
        one = ngs.LinearForm(ngs.CF(1.0) * l2.TestFunction() * dx)
        with backend._tm():
            one.Assemble()
        self.volumes = one.vec.FV().NumPy()[self.cells].copy()
        self._tm = backend._tm

    def _set(self, u_loc):
        u_loc = self._check_local(u_loc)
        first = np.zeros(len(self._unique), dtype=np.int64)
        first[self._pos[::-1]] = np.arange(len(self._pos))[::-1]  # one occurrence per unique cell
        vec = self._gf.vec.FV().NumPy()
        vec[:] = 0.0
        vec[self._dd] = np.einsum("ejl,el->ej", self._T, u_loc[first])

    def energies_and_forces(self, u_loc):
        self._set(u_loc)
        r = self._gf.vec.CreateVector()
        with self._tm():
            self._form.Apply(self._gf.vec, r)
            self._efun.Assemble()
        fe = np.einsum("ejl,ej->el", self._T, r.FV().NumPy()[self._dd])
        W = self._efun.vec.FV().NumPy()[self._unique]
        return W[self._pos].copy(), fe[self._pos]

    def forces_and_tangents(self, u_loc):
        self._set(u_loc)
        r = self._gf.vec.CreateVector()
        with self._tm():
            self._form.Apply(self._gf.vec, r)
            self._form.AssembleLinearization(self._gf.vec)
        vals, cols, rowptr = (np.asarray(a) for a in self._form.mat.CSR())
        K = sp.csr_matrix((vals.copy(), cols.copy(), rowptr.copy()), shape=(self._form.mat.height,) * 2)
        m = self._dd.shape[1]
        rows = np.repeat(self._dd, m, axis=1).ravel()
        colsb = np.tile(self._dd, (1, m)).ravel()
        blocks = np.asarray(K[rows, colsb]).reshape(len(self._unique), m, m)
        Ke = np.einsum("ejl,ejk,ekm->elm", self._T, blocks, self._T)
        fe = np.einsum("ejl,ej->el", self._T, r.FV().NumPy()[self._dd])
        return fe[self._pos], Ke[self._pos]
