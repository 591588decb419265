"""NGSolve backend: energies written symbolically and differentiated by NGSolve.

Independent of the NumPy material kernels of :mod:`~tissuebench.refsolvers.materials`:
each strain-energy density W(F) is a CoefficientFunction; ``Variation(W dx)`` gives
f_int (``Apply``), K_t (``AssembleLinearization``) and the energy (``Energy``).

NGSolve conventions met here (checked by ``tests/refsolvers/test_ngsolve_backend.py``):

* Vertex numbers and cell order are kept (``AddPoints``/``AddElements``).
* Netgen's tetrahedra have the opposite orientation to VTK's: a positive VTK tet
  ``(0, 1, 2, 3)`` is stored as ``(1, 0, 2, 3)``. Hexahedra keep the VTK order.
* NGSolve's reference tet has vertex k at barycentric ``lambda_k = x_k`` (k < 3) and
  vertex 3 at the origin; reference triangles likewise. The shared rules (unit simplex
  with vertex 0 at the origin) are mapped through barycentric coordinates, so both
  backends use the same physical points. Hexes and quads use the unit cube/square.
* A boundary ``Element2D`` whose vertices follow the right-hand rule outward has the
  outward ``specialcf.normal``; ``Grad`` of an H1 function on the boundary is the
  surface gradient, so ``Cof(I + Grad u) N`` is exactly cof(F) N.
* ``H1(order=2, nodalp2=True)`` is unusable in NGSolve 6.2.2608: its volume basis is
  nodal times 0.25, but the boundary traces use another basis (surface loads come out
  wrong). P2 therefore uses the hierarchical basis (vertex hats ``lambda_a``, edge
  bubbles equal to ``c = -1/8`` at their midpoint, both measured) and the sparse map
  ``d = T u`` from tissuebench's nodal values: ``f = T^T f_ng``, ``K = T^T K_ng T``.

Speed: ``AssembleLinearization`` of ``Variation(W dx)`` evaluates W with second-order
forward AD once per pair of the 9 components of Grad u (about 26 us per P1 cell,
interpreted). From :attr:`NgsolveBackend.REALCOMPILE_MIN_CELLS` cells the energy is
compiled to C++ (half the time); the TaskManager is entered only while a core is idle.
"""
from __future__ import annotations

import contextlib
import os
import shutil
import sys
import warnings
from functools import cached_property

import ngsolve as ngs
import numpy as np
import scipy.sparse as sp

from ..materials import Guccione, LinearElastic, MooneyRivlin, NeoHookean, NeoHookeanDecoupled, SaintVenantKirchhoff
from ..problem import BodyForce, FollowerPressure, SurfaceTraction
from ..quadrature import default_order, mass_order
from ..solver_base import idle_core
from ..sparse_direct import NgsolveSparseSolver
from ..._moved import moved
from .base import Backend, check_cells, lump_mass
from .ngsolve_cells import NgsolveCellKernel
from .ngsolve_mesh import build_ngsolve_mesh, make_intrules

# the mesh and rules helpers live in .ngsolve_mesh (below this module and its cell kernels, issue 55)
__getattr__ = moved(__name__, {"TET_TO_NG": "tissuebench.refsolvers.backends.ngsolve_mesh",
                               "simplex_rule_to_ng": "tissuebench.refsolvers.backends.ngsolve_mesh"})


# ---------------------------------------------------------------- energies
def energy_cf(material, F, fibre=None):
    """Strain-energy density W(F) as a CoefficientFunction (the definitions of :mod:`..materials`).

    ``fibre`` is a unit-vector CoefficientFunction (Guccione only).
    """
    I = ngs.Id(3)
    if isinstance(material, LinearElastic):
        lam, mu = material.lame
        eps = 0.5 * (F + F.trans) - I
        return 0.5 * lam * ngs.Trace(eps) ** 2 + mu * ngs.InnerProduct(eps, eps)
    C = F.trans * F
    E = 0.5 * (C - I)
    J = ngs.Det(F)
    if isinstance(material, SaintVenantKirchhoff):
        lam, mu = material.lame
        return 0.5 * lam * ngs.Trace(E) ** 2 + mu * ngs.InnerProduct(E, E)
    if isinstance(material, NeoHookeanDecoupled):  # before NeoHookean: not a subclass, but keep it explicit
        mu, kappa = material.lame[1], material.bulk_modulus
        return 0.5 * mu * (J ** (-2 / 3) * ngs.Trace(C) - 3) + 0.25 * kappa * (J ** 2 - 1 - 2 * ngs.log(J))
    if isinstance(material, NeoHookean):
        lam, mu = material.lame
        return 0.5 * mu * (ngs.Trace(C) - 3) - mu * ngs.log(J) + 0.5 * lam * ngs.log(J) ** 2
    if isinstance(material, MooneyRivlin):
        I1 = ngs.Trace(C)
        I2 = 0.5 * (I1 ** 2 - ngs.InnerProduct(C, C))
        return (0.5 * material.mu1 * (J ** (-2 / 3) * I1 - 3) + 0.5 * material.mu2 * (J ** (-4 / 3) * I2 - 3)
                + 0.5 * material.kappa * (J - 1) ** 2)
    if isinstance(material, Guccione):
        m = material
        Ef = E * fibre
        a = ngs.InnerProduct(fibre, Ef)
        Ef2 = ngs.InnerProduct(Ef, Ef)
        Q = m.bf * a ** 2 + m.bt * (ngs.InnerProduct(E, E) - 2 * Ef2 + a ** 2) + 2 * m.bfs * (Ef2 - a ** 2)
        return 0.5 * m.C * (ngs.exp(Q) - 1) + 0.5 * m.kappa * (J - 1) ** 2
    raise TypeError(f"NGSolve backend: no symbolic energy for {type(material).__name__}")


# ---------------------------------------------------------------- compiled energies
def _tool_path():
    """PATH with the interpreter's bin directory first: NGSolve's pip wheels install the
    ``ngscxx``/``ngsld`` compiler wrappers there, and they call ``python3`` to find NGSolve."""
    return os.path.dirname(sys.executable) + os.pathsep + os.environ.get("PATH", "")


def compiler_available() -> bool:
    """True if NGSolve's compiler wrapper and a C++ compiler can be found."""
    path = _tool_path()
    return bool(shutil.which("ngscxx", path=path) and shutil.which("ngsld", path=path) and shutil.which("c++"))


def real_compile(cf):
    """``(cf.Compile(realcompile=True), True)``, or ``(cf, False)`` with a warning if that fails."""
    old = os.environ.get("PATH", "")
    os.environ["PATH"] = _tool_path()  # NGSolve runs its wrappers through system()
    try:
        return cf.Compile(realcompile=True, wait=True), True
    except Exception as exc:  # noqa: BLE001 -- NgException (compiler missing or failing)
        warnings.warn(f"NGSolve realcompile failed, using the interpreted energy: {exc}", RuntimeWarning,
                      stacklevel=3)
        return cf, False
    finally:
        os.environ["PATH"] = old


# ---------------------------------------------------------------- CSR transfer
class _CsrTransfer:
    """Maps an NGSolve matrix to tissuebench numbering: ``K = T^T K_ng T``.

    ``T`` (NGSolve dof i <- tissuebench dofs ``cols[i]`` times ``vals[i]``, padded
    arrays of shape (ng_ndof, r)) is a scaled permutation for P1/Q1 (r = 1): then
    ``K[cols[i], cols[j]] = K_ng[i, j] w_i w_j`` by one gather whose index is computed
    from the first pattern and reused while the pattern is unchanged. P2 (r = 3) uses
    sparse products.
    """

    def __init__(self, cols, vals):
        self.ndof = int(cols.max()) + 1
        self.nnz = -1
        if cols.shape[1] == 1:
            self.perm, self.w, self.T = cols[:, 0], vals[:, 0], None
        else:
            rows = np.repeat(np.arange(len(cols)), cols.shape[1])
            self.T = sp.csr_matrix((vals.ravel(), (rows, cols.ravel())), shape=(len(cols), self.ndof))

    def _setup(self, cols, rowptr):
        n = len(self.perm)
        rows = np.repeat(np.arange(n), np.diff(rowptr))
        r, c = self.perm[rows], self.perm[cols]
        self.order = np.lexsort((c, r))
        self.indices = c[self.order].astype(np.int32)
        self.indptr = np.concatenate([[0], np.cumsum(np.bincount(r, minlength=n))]).astype(np.int32)
        self.factor = (self.w[rows] * self.w[cols])[self.order]
        self.nnz = len(cols)

    def __call__(self, mat):
        vals, cols, rowptr = (np.asarray(a) for a in mat.CSR())
        if self.T is not None:
            K = sp.csr_matrix((vals.copy(), cols.copy(), rowptr.copy()), shape=(mat.height, mat.width))
            return (self.T.T @ K @ self.T).tocsr()
        if len(vals) != self.nnz:
            self._setup(cols.astype(np.int64), rowptr.astype(np.int64))
        n = len(self.perm)
        return sp.csr_matrix((vals[self.order] * self.factor, self.indices.copy(), self.indptr.copy()),
                             shape=(n, n))


# ---------------------------------------------------------------- the backend
class NgsolveBackend(Backend):
    """Operators of a :class:`~tissuebench.refsolvers.problem.Problem` assembled by NGSolve.

    Parameters
    ----------
    problem : Problem
    threads : int or None
        Assemble inside NGSolve's TaskManager (None: NGSolve's default thread count for
        meshes of at least :attr:`TASKMANAGER_MIN_CELLS` cells while a core is idle
        (:func:`~tissuebench.refsolvers.solver_base.idle_core`, checked per call), serial
        otherwise; 1: no TaskManager; n > 1: ``SetNumThreads(n)``, a process-wide setting).
    realcompile : bool or None
        Compile the energy of f_int and K_t to C++ (NGSolve's ``realcompile``, with the
        ``ngscxx`` installed beside the interpreter). None: for meshes of at least
        :attr:`REALCOMPILE_MIN_CELLS` cells when a C++ compiler is found. If compilation
        fails the interpreted energy is used, with a warning; :attr:`compiled` says which.
    """

    #: below this many cells, entering the TaskManager costs more than the threads save
    #: (and its workers spin-wait when the machine is loaded: 0.5 s per call measured on the
    #: 96-cell wave block under a concurrent test run)
    TASKMANAGER_MIN_CELLS = 2000
    #: from this many cells the one-off compilation (5-20 s) pays: compiled, the tangent of
    #: the 37800-cell bar takes 0.50 s of CPU instead of 0.98 s and f_int 0.085 s instead of 0.175 s
    REALCOMPILE_MIN_CELLS = 20000

    name = "ngsolve"

    def __init__(self, problem, threads=None, realcompile=None):
        super().__init__(problem)
        pb = problem
        if threads is None and pb.mesh.n_cells < self.TASKMANAGER_MIN_CELLS:
            threads = 1
        self._threads = threads
        if threads and threads > 1:
            ngs.SetNumThreads(int(threads))
        self._order = pb.quadrature_order or default_order(pb.element)
        self._surface_loads = [ld for ld in pb.loads if isinstance(ld, (SurfaceTraction, FollowerPressure))]
        self.ngmesh = build_ngsolve_mesh(pb.mesh, [pb.facets_of(ld) for ld in self._surface_loads])
        self.fes = ngs.VectorH1(self.ngmesh, order=2 if pb.element == "P2" else 1)
        self._Tcols, self._Tvals = self._dof_map()
        self._gfu = ngs.GridFunction(self.fes)
        self._dx = ngs.dx(intrules=make_intrules(pb.element, self._order))
        self._a_int = ngs.BilinearForm(self.fes, symmetric=True)
        if realcompile is None:
            realcompile = pb.mesh.n_cells >= self.REALCOMPILE_MIN_CELLS and compiler_available()
        W = self._energy(self.fes.TrialFunction(), compile=False)
        self.compiled = False
        if realcompile:
            W, self.compiled = real_compile(W)
        self._a_int += ngs.Variation((W if self.compiled else W.Compile()) * self._dx)
        self._K_int = _CsrTransfer(self._Tcols, self._Tvals)
        self._K_ext = _CsrTransfer(self._Tcols, self._Tvals)

    # ------------------------------------------------------------ numbering
    def _dof_map(self):
        """The map ``d = T u`` from tissuebench values to NGSolve coefficients.

        Returns
        -------
        cols, vals : ndarray, shape (ng_ndof, r)
            ``d[i] = sum_k vals[i, k] * u[cols[i, k]]``; r = 1 (P1, Q1) or 3 (P2:
            ``d_e = (u_e - (u_a + u_b) / 2) / c`` for the bubble of edge (a, b)).
        """
        m, fes, p2 = self.ngmesh, self.fes, self.problem.element == "P2"
        comp = np.arange(3)
        cols = np.full((fes.ndof, 3 if p2 else 1), -1, dtype=np.int64)
        vals = np.zeros(cols.shape)
        vd = np.array([fes.GetDofNrs(ngs.NodeId(ngs.VERTEX, v)) for v in range(m.nv)], dtype=np.int64)
        cols[vd] = (3 * np.arange(m.nv)[:, None] + comp)[..., None]
        vals[vd, 0] = 1.0 / self._basis_value(vd[0, 0], self.problem.nodes[0])
        if p2:
            ev = np.sort([[a.nr, b.nr] for a, b in (e.vertices for e in m.edges)], axis=1)
            tbe = self.problem.mesh.edges
            node = m.nv + np.searchsorted(tbe[:, 0] * m.nv + tbe[:, 1], ev[:, 0] * m.nv + ev[:, 1])
            ed = np.array([fes.GetDofNrs(ngs.NodeId(ngs.EDGE, e)) for e in range(m.nedge)], dtype=np.int64)
            c = self._basis_value(ed[0, 0], self.problem.nodes[node[0]])
            for k, n in enumerate((node, ev[:, 0], ev[:, 1])):
                cols[ed, k] = 3 * n[:, None] + comp
            vals[ed] = [1.0 / c, -0.5 / c, -0.5 / c]
        if (cols < 0).any() or len(np.unique(cols[:, 0])) != len(cols) or len(cols) != self.ndof:
            raise RuntimeError("NGSolve dofs do not map one-to-one onto tissuebench nodes")
        return cols, vals

    def _basis_value(self, dof, x):
        """Value (component 0) of NGSolve basis function ``dof`` at point ``x``."""
        gf = ngs.GridFunction(self.fes)
        gf.vec[:] = 0.0
        gf.vec[int(dof)] = 1.0
        return gf(self.ngmesh(*map(float, x)))[0]

    def _set_u(self, u):
        u = self._check_u(u)
        self._gfu.vec.FV().NumPy()[:] = np.einsum("ir,ir->i", self._Tvals, u[self._Tcols])
        return self._gfu

    def _to_tb(self, vec):
        """NGSolve dual vector -> tissuebench vector, ``T^T r``."""
        w = self._Tvals * vec.FV().NumPy()[:, None]
        return np.bincount(self._Tcols.ravel(), weights=w.ravel(), minlength=self.ndof)

    # ------------------------------------------------------------ material
    @cached_property
    def _fibre(self):
        """Fibre direction CoefficientFunction (Guccione), per-cell via L2 order 0."""
        mat = self.problem.material
        if not isinstance(mat, Guccione):
            return None
        f = np.asarray(mat.fibres, dtype=float)
        if f.ndim == 1:
            return ngs.CF(tuple(float(c) for c in f))
        l2 = ngs.L2(self.ngmesh, order=0)  # dof i = element i = cell i
        self._fibre_gfs = [ngs.GridFunction(l2) for _ in range(3)]
        for c, g in enumerate(self._fibre_gfs):
            g.vec.FV().NumPy()[:] = f[:, c]
        return ngs.CF(tuple(self._fibre_gfs))

    def _energy(self, u, compile=True):
        W = energy_cf(self.problem.material, ngs.Id(3) + ngs.Grad(u), self._fibre)
        return W.Compile() if compile else W

    def _tm(self):
        """TaskManager context for assembly (a no-op with ``threads=1`` or, by default, when
        no core is idle)."""
        if self._threads == 1 or (self._threads is None and not idle_core()):
            return contextlib.nullcontext()
        return ngs.TaskManager()

    # ------------------------------------------------------------ internal
    def internal_force(self, u):
        gfu = self._set_u(u)
        r = gfu.vec.CreateVector()
        with self._tm():
            self._a_int.Apply(gfu.vec, r)
        return self._to_tb(r)

    def tangent(self, u):
        gfu = self._set_u(u)
        with self._tm():
            self._a_int.AssembleLinearization(gfu.vec)
        return self._K_int(self._a_int.mat)

    def internal_force_and_tangent(self, u):
        return self.internal_force(u), self.tangent(u)

    def strain_energy(self, u):
        gfu = self._set_u(u)
        with self._tm():
            return float(self._a_int.Energy(gfu.vec))

    @cached_property
    def _element_energy_form(self):
        w = ngs.L2(self.ngmesh, order=0).TestFunction()  # basis 1 on element i
        return ngs.LinearForm(self._energy(self._gfu) * w * self._dx)

    def element_strain_energies(self, u):
        self._set_u(u)
        with self._tm():
            return self._element_energy_form.Assemble().vec.FV().NumPy().copy()

    @cached_property
    def _dc(self):
        """Discontinuous copy of the space and the maps of its element blocks.

        Returns (gridfunction, form, cd, dd, flat, w): ``cd``/``dd`` (n_cells, m) continuous
        and discontinuous NGSolve dofs per cell; element vectors go to tissuebench
        local order by ``bincount(flat, w * r[dd][..., None])`` (``flat``, ``w`` of shape
        (n_cells, m, r)).
        """
        fes_dc = ngs.Discontinuous(self.fes)
        gf = ngs.GridFunction(fes_dc)
        a = ngs.BilinearForm(fes_dc, symmetric=True)
        a += ngs.Variation(self._energy(fes_dc.TrialFunction()) * self._dx)
        ids = [ngs.ElementId(ngs.VOL, i) for i in range(self.ngmesh.ne)]
        cd = np.array([self.fes.GetDofNrs(el) for el in ids], dtype=np.int64)
        dd = np.arange(fes_dc.ndof).reshape(cd.shape)  # blocks per element; spot-checked
        if any(fes_dc.GetDofNrs(ids[i]) != tuple(dd[i]) for i in {0, len(ids) // 2, len(ids) - 1}):
            dd = np.array([fes_dc.GetDofNrs(el) for el in ids], dtype=np.int64)
        edofs = self.element_dofs()
        n, mloc = edofs.shape
        order = np.argsort(edofs, axis=1)
        keys = (np.arange(n)[:, None] * self.ndof + np.take_along_axis(edofs, order, axis=1)).ravel()
        target = np.arange(n)[:, None, None] * self.ndof + self._Tcols[cd]
        idx = np.searchsorted(keys, target)
        if not np.array_equal(keys[np.minimum(idx, keys.size - 1)], target):
            raise RuntimeError("element dofs of NGSolve and tissuebench differ")
        flat = idx - (idx % mloc) + np.take_along_axis(order, (idx % mloc).reshape(n, -1), axis=1).reshape(idx.shape)
        return gf, a, cd, dd, flat, self._Tvals[cd]

    def element_internal_forces(self, u):
        d = self._set_u(u).vec.FV().NumPy()
        gf, a, cd, dd, flat, w = self._dc
        gf.vec.FV().NumPy()[dd] = d[cd]
        r = gf.vec.CreateVector()
        with self._tm():
            a.Apply(gf.vec, r)
        fe = w * r.FV().NumPy()[dd][..., None]
        return np.bincount(flat.ravel(), weights=fe.ravel(), minlength=flat.shape[0] * flat.shape[1]).reshape(
            flat.shape[0], -1)

    def cell_kernel(self, cells=None):
        return NgsolveCellKernel(self, check_cells(cells, self.problem.mesh.n_cells))

    @cached_property
    def _qp(self):
        return self.ngmesh.MapToAllElements(make_intrules(self.problem.element, self._order), ngs.VOL)

    def min_jacobian(self, u):
        gfu = self._set_u(u)
        return float(np.min(ngs.Det(ngs.Id(3) + ngs.Grad(gfu))(self._qp)))

    # ------------------------------------------------------------ loads
    def _ds(self, k):
        return ngs.ds(definedon=self.ngmesh.Boundaries(f"load{k}"),
                      intrules=make_intrules(self.problem.element, self._order, facet=True))

    @cached_property
    def _dead_load(self):
        """Point loads, dead tractions and body forces at load factor 1, shape (ndof,)."""
        f = self.problem.point_load_vector()
        v = self.fes.TestFunction()
        terms = [ngs.InnerProduct(ngs.CF(tuple(map(float, ld.traction))), v) * self._ds(k)
                 for k, ld in enumerate(self._surface_loads) if isinstance(ld, SurfaceTraction)]
        terms += [ngs.InnerProduct(ngs.CF(tuple(map(float, ld.force))), v) * self._dx
                  for ld in self.problem.loads if isinstance(ld, BodyForce)]
        if terms:
            lf = ngs.LinearForm(self.fes)
            for t in terms:
                lf += t
            f = f + self._to_tb(lf.Assemble().vec)
        return f

    @cached_property
    def _pressure_form(self):
        """Follower pressure form -p cof(F) N . v dA (unit load factor), or None."""
        u, v = self.fes.TnT()
        cofN = ngs.Cof(ngs.Id(3) + ngs.Grad(u).Trace()) * ngs.specialcf.normal(3)
        terms = [-float(ld.pressure) * ngs.InnerProduct(cofN, v) * self._ds(k)
                 for k, ld in enumerate(self._surface_loads) if isinstance(ld, FollowerPressure)]
        if not terms:
            return None
        a = ngs.BilinearForm(self.fes)
        for t in terms:
            a += t
        return a

    def external_force(self, u, load_factor):
        f = load_factor * self._dead_load
        if self._pressure_form is None:
            self._check_u(u)
            return f
        gfu = self._set_u(u)
        r = gfu.vec.CreateVector()
        with self._tm():
            self._pressure_form.Apply(gfu.vec, r)
        return f + load_factor * self._to_tb(r)

    def external_tangent(self, u, load_factor):
        if self._pressure_form is None:
            return None
        gfu = self._set_u(u)
        with self._tm():
            self._pressure_form.AssembleLinearization(gfu.vec)
        return load_factor * self._K_ext(self._pressure_form.mat)

    # ------------------------------------------------------------ mass, solver
    @cached_property
    def _mass(self):
        u, v = self.fes.TnT()
        dxm = ngs.dx(intrules=make_intrules(self.problem.element, mass_order(self.problem.element)))
        a = ngs.BilinearForm(self.fes, symmetric=True)
        a += float(self.problem.density) * ngs.InnerProduct(u, v) * dxm
        return _CsrTransfer(self._Tcols, self._Tvals)(a.Assemble().mat)

    def mass(self, lumped=False):
        return lump_mass(self._mass, self.problem.element) if lumped else self._mass.copy()

    def make_linear_solver(self, name="auto", **options):
        """``"direct"``: NGSolve's sparse Cholesky/UMFPACK (:class:`NgsolveSparseSolver`, also
        ``"cholesky"`` on every backend); ``"auto"``: the same, with its factors kept for CG from
        :data:`~tissuebench.refsolvers.linear_solvers.KEPT_FACTORS_MIN_DOFS` unknowns on
        (:class:`~tissuebench.refsolvers.linear_solvers.AutoDirectSolver` taking NGSolve at every
        size); other names: the shared solvers."""
        if name == "direct":
            return NgsolveSparseSolver(**options)
        if name == "auto":
            from ..linear_solvers import AutoDirectSolver

            return AutoDirectSolver(ngsolve_from=0, **options)
        return super().make_linear_solver(name, **options)
