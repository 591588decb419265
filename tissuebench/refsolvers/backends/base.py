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
* Quadrature: both backends integrate with the same rules,
  :func:`~tissuebench.refsolvers.quadrature.volume_rule`, so they agree to round-off
  on the same mesh for any material.
"""
from __future__ import annotations

from abc import ABC, abstractmethod

import numpy as np
import scipy.sparse as sp


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
        """Consistent mass (density * N_a N_b, times I3), or its row-sum lumped diagonal."""

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

    # -------------------------------------------------------------- helpers
    def element_dofs(self) -> np.ndarray:
        """Global dofs of each cell's local dofs, shape (n_cells, 3 * n_local_nodes)."""
        cells = self.problem.layout[1]
        return (3 * cells[:, :, None] + np.arange(3)).reshape(len(cells), -1)

    def make_linear_solver(self, name: str = "direct", **options):
        """A linear solver for this backend (see :mod:`tissuebench.refsolvers.linear_solvers`)."""
        from ..linear_solvers import make_linear_solver

        return make_linear_solver(name, **options)

    def _check_u(self, u):
        u = np.asarray(u, dtype=float)
        if u.shape != (self.ndof,):
            raise ValueError(f"u must have shape ({self.ndof},), got {u.shape}")
        return u


BACKENDS: dict[str, str] = {
    "skfem": "tissuebench.refsolvers.backends.skfem_backend:SkfemBackend",
    "ngsolve": "tissuebench.refsolvers.backends.ngsolve_backend:NgsolveBackend",
}


def make_backend(name, problem) -> Backend:
    """Instantiate a backend by name (``"skfem"``, ``"ngsolve"``) or class."""
    if isinstance(name, type) and issubclass(name, Backend):
        return name(problem)
    if name not in BACKENDS:
        raise ValueError(f"unknown backend {name!r}; valid: {sorted(BACKENDS)}")
    import importlib

    module, cls = BACKENDS[name].split(":")
    return getattr(importlib.import_module(module), cls)(problem)
