"""Shared helpers for the verification tests (meshes, solves, error norms).

The L2-error helper evaluates finite-element fields with scikit-fem directly (its own
bases and a high-order quadrature), independently of the backends under test, so the
same helper measures the solutions of every backend.
"""
from __future__ import annotations

import numpy as np
import pytest
import skfem
from skfem.quadrature import get_quadrature
from skfem.refdom import RefHex, RefTet

from tissuebench.cases.meshes import box_mesh
from tissuebench.refsolvers.backends import make_backend
from tissuebench.refsolvers.mesh import Mesh
from tissuebench.refsolvers.newton import newton_solve

BACKEND_PARAMS = ["skfem", pytest.param("ngsolve", marks=pytest.mark.ngsolve)]
ELEMENTS = ["P1", "P2", "Q1"]
CELL_OF = {"P1": "tetra", "P2": "tetra", "Q1": "hexahedron"}

# skfem's local vertex order of MeshHex1 expressed in VTK hexahedron order
_VTK_TO_SKFEM_HEX = [0, 4, 3, 1, 7, 5, 2, 6]


def element_mesh(element, lengths=(1.0, 1.0, 1.0), divisions=(1, 1, 1), jitter=0.0, seed=0) -> Mesh:
    """box_mesh with the cell type ``element`` needs."""
    return box_mesh(lengths, divisions, CELL_OF[element], jitter=jitter, seed=seed)


def on_plane(axis, value, tol=1e-9):
    """Predicate ``x -> mask`` selecting points with ``x[:, axis] == value``."""
    return lambda x: np.abs(x[:, axis] - value) <= tol


def on_box_boundary(lengths=(1.0, 1.0, 1.0), tol=1e-9):
    L = np.asarray(lengths, float)
    return lambda x: np.any((np.abs(x) <= tol) | (np.abs(x - L) <= tol), axis=1)


def solve(problem, backend_name, load_factor=1.0, **newton_kw):
    """Build the backend, run Newton (strict), return (backend, result)."""
    b = make_backend(backend_name, problem)
    res = newton_solve(b, load_factor, strict=True, **newton_kw)
    assert res.success and np.all(np.isfinite(res.u))
    return b, res


# --------------------------------------------------------------------------- L2 error
def _skfem_basis(mesh: Mesh, element: str, order: int):
    if element == "Q1":
        skm = skfem.MeshHex(mesh.points.T.copy(), mesh.cells[:, _VTK_TO_SKFEM_HEX].T.copy())
        elem, ref = skfem.ElementHex1(), RefHex
    else:
        skm = skfem.MeshTet(mesh.points.T.copy(), mesh.cells.T.copy())
        elem, ref = (skfem.ElementTetP2() if element == "P2" else skfem.ElementTetP1()), RefTet
    basis = skfem.Basis(skm, elem, quadrature=get_quadrature(ref, order))
    # tissuebench node index of each skfem scalar dof
    nmap = np.empty(basis.N, dtype=np.int64)
    nmap[basis.nodal_dofs[0]] = np.arange(mesh.n_vertices)
    if element == "P2":
        nv = mesh.n_vertices
        sk_edges = np.sort(skm.edges.T, axis=1)
        ours = mesh.edges
        ids = np.searchsorted(ours[:, 0] * nv + ours[:, 1], sk_edges[:, 0] * nv + sk_edges[:, 1])
        assert np.array_equal(ours[ids], sk_edges)
        nmap[basis.edge_dofs[0]] = nv + ids
    return basis, nmap


def l2_error(mesh: Mesh, element: str, u: np.ndarray, exact, order: int = 6):
    """(||u_h - u||_L2, ||u||_L2) with ``exact(x) -> (n, 3)`` and ``u`` node-major (ndof,)."""
    basis, nmap = _skfem_basis(mesh, element, order)
    U = np.asarray(u, float).reshape(-1, 3)
    assert len(U) == basis.N, (len(U), basis.N)
    xq = basis.global_coordinates().value  # (3, n_cells, n_qp)
    pts = xq.reshape(3, -1).T
    ue = np.asarray(exact(pts), float).T.reshape(xq.shape)
    dx = np.asarray(basis.dx)
    err2 = 0.0
    for c in range(3):
        uh = basis.interpolate(U[nmap, c]).value
        err2 += float(np.sum(dx * (uh - ue[c]) ** 2))
    ref2 = float(np.sum(dx * np.sum(ue ** 2, axis=0)))
    return np.sqrt(err2), np.sqrt(ref2)


def fitted_order(h, err):
    """Least-squares slope of log(err) versus log(h)."""
    return float(np.polyfit(np.log(h), np.log(err), 1)[0])


# --------------------------------------------------------------------------- materials
def material_set(fibres=None):
    """One instance per registered material (moderate, comparable stiffness ~1)."""
    from tissuebench.refsolvers.materials import (Guccione, LinearElastic, MooneyRivlin, NeoHookean,
                                                  NeoHookeanDecoupled, SaintVenantKirchhoff)
    f = np.array([1.0, 1.0, 0.0]) / np.sqrt(2.0) if fibres is None else fibres
    return {
        "linear": LinearElastic(E=1.0, nu=0.3),
        "svk": SaintVenantKirchhoff(E=1.0, nu=0.3),
        "neo_hookean": NeoHookean(E=1.0, nu=0.3),
        "neo_hookean_decoupled": NeoHookeanDecoupled(E=1.0, nu=0.3),
        "mooney_rivlin": MooneyRivlin(mu1=0.2, mu2=0.15, kappa=2.0),
        "guccione": Guccione(C=0.2, bf=8.0, bt=2.0, bfs=4.0, kappa=2.0, fibres=f),
    }


MATERIAL_NAMES = ["linear", "svk", "neo_hookean", "neo_hookean_decoupled", "mooney_rivlin", "guccione"]
