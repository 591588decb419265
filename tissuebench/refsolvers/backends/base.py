"""The contract every finite-element backend fulfils.

A backend turns a :class:`~tissuebench.refsolvers.problem.Problem` into operators.
Solvers (Newton, HHT, Bathe, explicit) and every ROM consume only this interface and
never import a backend module.

Conventions
-----------
* Vectors have length ``ndof = 3 * n_nodes``, node-major (dof ``3*node + c``), nodes as
  in :func:`~tissuebench.refsolvers.mesh.node_layout`; this holds on every backend, so
  a displacement computed on one backend can be fed to the other.
* Matrices are ``scipy.sparse.csr_matrix`` of shape ``(ndof, ndof)`` on all dofs;
  Dirichlet conditions are applied by the solvers, not by the backend.
* ``internal_force(u)`` = d(strain energy)/du; ``tangent(u)`` = d internal_force / du.
* ``external_force(u, lam)`` = all loads at load factor ``lam`` (follower pressure
  depends on ``u``); ``external_tangent(u, lam)`` = d external_force / du (``None`` when
  no load depends on ``u``).
* Element quantities are indexed by mesh cell; local dofs follow the node order of
  ``problem.layout[1]`` (node-major, xyz).
* Element quantities of a *subset* of cells (cubature elements of a reduced model) come
  from :meth:`Backend.cell_kernel`: a :class:`CellKernel` evaluates energies, element
  force vectors and element tangents from the cells' local displacements only, so its
  cost is O(len(cells)), never O(mesh).
* Quadrature: both backends integrate with the same rules,
  :func:`~tissuebench.refsolvers.quadrature.volume_rule`, so they agree to round-off
  on the same mesh for any material.
"""
from __future__ import annotations

from abc import ABC, abstractmethod

import numpy as np
import scipy.sparse as sp

from ...choices import BACKEND_NAMES


class Backend(ABC):
    """Operators of one problem on one finite-element library."""

    name: str = ""

    def __init__(self, problem):
        self.problem = problem

    # -------------------------------------------------------------- sizes
    @property
    def ndof(self) -> int:
        return self.problem.ndof

    # -------------------------------------------------------------- operators
    @abstractmethod
    def internal_force(self, u: np.ndarray) -> np.ndarray:
        """f_int(u), shape (ndof,)."""

    @abstractmethod
    def tangent(self, u: np.ndarray) -> sp.csr_matrix:
        """K_t(u) = d f_int / du, CSR (ndof, ndof)."""

    def internal_force_and_tangent(self, u):
        """Both at once (backends may share the work)."""
        return self.internal_force(u), self.tangent(u)

    @abstractmethod
    def external_force(self, u: np.ndarray, load_factor: float) -> np.ndarray:
        """All loads at ``load_factor`` in configuration ``u``, shape (ndof,)."""

    @abstractmethod
    def external_tangent(self, u: np.ndarray, load_factor: float) -> sp.csr_matrix | None:
        """d external_force / du (follower loads), or None if loads are dead."""

    @abstractmethod
    def mass(self, lumped: bool = False) -> sp.csr_matrix:
        """Consistent mass (density * N_a N_b, times I3), or its lumped diagonal (:func:`lump_mass`)."""

    @abstractmethod
    def strain_energy(self, u: np.ndarray) -> float:
        """Total stored energy integral of W over the reference volume."""

    @abstractmethod
    def element_strain_energies(self, u: np.ndarray) -> np.ndarray:
        """Per-cell stored energy, shape (n_cells,)."""

    @abstractmethod
    def element_internal_forces(self, u: np.ndarray) -> np.ndarray:
        """Per-cell internal force vectors, shape (n_cells, 3 * n_local_nodes)."""

    @abstractmethod
    def min_jacobian(self, u: np.ndarray) -> float:
        """Smallest det F over all quadrature points (<= 0 means an inverted element)."""

    # -------------------------------------------------------------- cell subsets
    def cell_kernel(self, cells=None) -> "CellKernel":
        """Element operators restricted to ``cells`` (all cells when None).

        Parameters
        ----------
        cells : (m,) int array, optional
            Mesh cell indices (duplicates allowed; order kept).

        Returns
        -------
        CellKernel
            Evaluates from local displacements ``u_loc`` of shape (m, n_loc), with
            ``n_loc = 3 * nodes per cell`` in the order of :meth:`element_dofs`.
        """
        raise NotImplementedError(f"{type(self).__name__} does not provide cell kernels")

    def element_forces_and_tangents(self, u, cells=None):
        """Element internal force vectors (m, n_loc) and tangents (m, n_loc, n_loc) of
        ``cells`` (all when None) at the full displacement ``u`` (ndof,)."""
        kernel = self.cell_kernel(cells)
        return kernel.forces_and_tangents(kernel.gather(self._check_u(u)))

    def element_energies_and_forces(self, u, cells=None):
        """Element strain energies (m,) and internal force vectors (m, n_loc) of ``cells``."""
        kernel = self.cell_kernel(cells)
        return kernel.energies_and_forces(kernel.gather(self._check_u(u)))

    # -------------------------------------------------------------- helpers
    def element_dofs(self) -> np.ndarray:
        """Global dofs of each cell's local dofs, shape (n_cells, 3 * n_local_nodes)."""
        cells = self.problem.layout[1]
        return (3 * cells[:, :, None] + np.arange(3)).reshape(len(cells), -1)

    def make_linear_solver(self, name: str = "auto", **options):
        """A linear solver for this backend (see :mod:`tissuebench.refsolvers.linear_solvers`)."""
        from ..linear_solvers import make_linear_solver

        return make_linear_solver(name, **options)

    def _check_u(self, u):
        u = np.asarray(u, dtype=float)
        if u.shape != (self.ndof,):
            raise ValueError(f"u must have shape ({self.ndof},), got {u.shape}")
        return u


def check_cells(cells, n_cells) -> np.ndarray:
    """``cells`` as an int64 array of cell indices in range, or ValueError naming the value."""
    if cells is None:
        return np.arange(n_cells, dtype=np.int64)
    arr = np.asarray(cells)
    if arr.ndim != 1 or not (arr.size == 0 or np.issubdtype(arr.dtype, np.integer)):
        raise ValueError(f"cells must be a 1D integer array of cell indices, got shape {arr.shape}, "
                         f"dtype {arr.dtype}")
    if arr.size and (arr.min() < 0 or arr.max() >= n_cells):
        raise ValueError(f"cells: index out of range 0..{n_cells - 1} (min {arr.min()}, max {arr.max()})")
    return arr.astype(np.int64)


class CellKernel(ABC):
    """Element operators of a fixed set of cells, from the cells' local displacements.

    Attributes
    ----------
    cells : (m,) int array
        Mesh cell indices.
    dofs : (m, n_loc) int array
        Global dofs of each cell's local dofs (node-major, xyz; see ``Backend.element_dofs``).
    volumes : (m,) array
        Reference volumes of the cells (quadrature of 1).
    """

    cells: np.ndarray
    dofs: np.ndarray
    volumes: np.ndarray

    def gather(self, u: np.ndarray) -> np.ndarray:
        """Local displacements (m, n_loc) of the full vector ``u`` (ndof,)."""
        return np.asarray(u, dtype=float)[self.dofs]

    def _check_local(self, u_loc) -> np.ndarray:
        u_loc = np.asarray(u_loc, dtype=float)
        if u_loc.shape != self.dofs.shape:
            raise ValueError(f"u_loc must have shape {self.dofs.shape} (cells, local dofs), got {u_loc.shape}")
        return u_loc

    @abstractmethod
    def energies_and_forces(self, u_loc: np.ndarray):
        """Strain energies (m,) and internal force vectors (m, n_loc)."""

    @abstractmethod
    def forces_and_tangents(self, u_loc: np.ndarray):
        """Internal force vectors (m, n_loc) and tangents d f_e / d u_e (m, n_loc, n_loc)."""

    def energies(self, u_loc):
        return self.energies_and_forces(u_loc)[0]

    def forces(self, u_loc):
        return self.energies_and_forces(u_loc)[1]


def material_on_cells(material, cells):
    """``material`` restricted to ``cells``: per-cell data (Guccione fibres (n_cells, 3)) sliced."""
    import dataclasses

    fibres = getattr(material, "fibres", None)
    if fibres is not None and np.ndim(fibres) == 2 and dataclasses.is_dataclass(material):
        return dataclasses.replace(material, fibres=np.asarray(fibres)[cells])
    return material


def lump_mass(M, element: str) -> sp.csr_matrix:
    """The diagonal (lumped) mass of a consistent mass ``M`` of ``element``.

    P1 and Q1: the row sums. P2: HRZ lumping (Hinton, Rock & Zienkiewicz 1976), the diagonal
    of M scaled to keep the total mass; the row sums of a quadratic tetrahedron's mass are
    negative at its vertices (-1/20 of the cell's mass), which no integrator accepts. On
    straight-sided P2 cells the diagonal carries the same fraction of every cell's mass
    (216/420), so scaling the assembled diagonal is the cell-by-cell HRZ. On P1 the two
    lumpings coincide.
    """
    if element != "P2":
        return sp.diags(np.asarray(M.sum(axis=1)).ravel(), format="csr")
    d = M.diagonal()
    return sp.diags(d * (float(M.sum()) / float(d.sum())), format="csr")


BACKENDS: dict[str, str] = {
    "skfem": "tissuebench.refsolvers.backends.skfem_backend:SkfemBackend",
    "ngsolve": "tissuebench.refsolvers.backends.ngsolve_backend:NgsolveBackend",
}
if tuple(BACKENDS) != BACKEND_NAMES:  # the one list of names (tissuebench.choices); not an assert: -O
    raise ImportError(f"BACKENDS {tuple(BACKENDS)} differ from tissuebench.choices.BACKEND_NAMES {BACKEND_NAMES}")


def make_backend(name, problem) -> Backend:
    """Instantiate a backend by name (``"skfem"``, ``"ngsolve"``) or class."""
    if isinstance(name, type) and issubclass(name, Backend):
        return name(problem)
    if name not in BACKENDS:
        raise ValueError(f"unknown backend {name!r}; valid: {sorted(BACKENDS)}")
    import importlib

    module, cls = BACKENDS[name].split(":")
    return getattr(importlib.import_module(module), cls)(problem)
