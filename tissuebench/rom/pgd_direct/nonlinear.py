"""Separated internal force of a Saint Venant-Kirchhoff model on the previous displacement.

With ``u_n = sum_j phi_j q_j`` the SVK internal force is a cubic polynomial of the
coordinates (:mod:`tissuebench.rom.polynomial`):

    f_int(u_n) = sum_j K phi_j q_j + sum_{j<=k} c_jk Q(phi_j, phi_k) q_j q_k
                 + sum_{j<=k<=l} c_jkl C(phi_j, phi_k, phi_l) q_j q_k q_l,

with multiplicities ``c`` (1 for a repeated index set, 2 or 3 or 6 otherwise). Each
monomial is one separated term: its full-size vector times the powers of the
coordinates' nodal values in their dimensions. This is the explicit treatment of the
nonlinearity of the paper (§6.2): an explicit inner integrator evaluates ``f_int(u_n)``,
so the PGD problem of the step stays linear in the unknown. The nodal values of
``q_j^2`` and ``q_j^3`` are interpolated linearly online, the source of the
parameter-mesh error (second order in the element size) of the nonlinear vademecum.
"""
from __future__ import annotations

import itertools
import math

import numpy as np

from ..polynomial import CubicForce, MultilinearTerms
from .fields import SepField

__all__ = ["svk_internal_force_field"]


def _term(vector, powers: dict, meshes) -> SepField:
    factors = [np.ones((m.n_nodes, 1)) for m in meshes]
    for d, k in powers.items():
        factors[d][:, 0] = meshes[d].nodes ** k
    return SepField(np.asarray(vector, dtype=float).reshape(-1, 1), factors)


def svk_internal_force_field(backend, basis, dims, meshes, free_dofs=None):
    """``f_int(sum_j basis[:, j] p_{dims[j]})`` as a SepField on the free dofs.

    Parameters
    ----------
    backend : Backend
        A polynomial model (SVK or linear material, dead loads, homogeneous Dirichlet).
    basis : (n_free, m) array
        Displacement basis.
    dims : sequence of int
        Parameter dimension of each coordinate.
    meshes : list of ParameterMesh
    free_dofs : (n_free,) int array, optional

    Returns
    -------
    field : SepField
        ``m + m(m+1)/2 + m(m+1)(m+2)/6`` terms (m = 8: 164).
    n_evals : int
        Internal-force evaluations used by the polarisation (offline cost).
    """
    basis = np.asarray(basis, dtype=float)
    m = basis.shape[1]
    force = CubicForce(backend, dofs=free_dofs)
    terms = MultilinearTerms(force)
    for j in range(m):
        terms.add(basis[:, j])
    parts = [_term(force.K0 @ basis[:, j], {dims[j]: 1}, meshes) for j in range(m)]
    for j, k in itertools.combinations_with_replacement(range(m), 2):
        mult = 1.0 if j == k else 2.0
        powers = {dims[j]: 2} if j == k else {dims[j]: 1, dims[k]: 1}
        parts.append(_term(mult * terms.q(j, k), powers, meshes))
    for idx in itertools.combinations_with_replacement(range(m), 3):
        counts = {i: idx.count(i) for i in set(idx)}
        mult = 6.0 / np.prod([math.factorial(c) for c in counts.values()])
        parts.append(_term(mult * terms.c(*idx), {dims[i]: c for i, c in counts.items()}, meshes))
    out = parts[0]
    for p in parts[1:]:
        out = out + p
    return out, force.n_evals
