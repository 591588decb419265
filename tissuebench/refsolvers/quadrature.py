"""Quadrature rules shared by both backends (so they integrate identically).

Rules come from scikit-fem; reference cells are the unit tetrahedron
{x, y, z >= 0, x + y + z <= 1} and the unit cube [0, 1]^3, which are also NGSolve's.
"""
from __future__ import annotations

from skfem.quadrature import get_quadrature
from skfem.refdom import RefHex, RefTet, RefTri, RefQuad

_STIFFNESS_ORDER = {"P1": 1, "P2": 4, "Q1": 3}
_MASS_ORDER = {"P1": 2, "P2": 4, "Q1": 3}


def default_order(element: str) -> int:
    """Order for f_int, K_t, energies and loads: P1 1 (F is constant, exact for every
    material), P2 4 (exact for SVK), Q1 3 (2x2x2 Gauss)."""
    return _STIFFNESS_ORDER[element]


def mass_order(element: str) -> int:
    """Order for the consistent mass matrix (exact: 2 p)."""
    return _MASS_ORDER[element]


def volume_rule(element: str, order: int | None = None):
    """(points (3, n_qp), weights (n_qp,)) on the reference cell of ``element``."""
    ref = RefHex if element == "Q1" else RefTet
    return get_quadrature(ref, order or default_order(element))


def facet_rule(element: str, order: int | None = None):
    """(points (2, n_qp), weights (n_qp,)) on the reference facet (triangle or unit square)."""
    ref = RefQuad if element == "Q1" else RefTri
    return get_quadrature(ref, order or default_order(element))
