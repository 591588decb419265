"""Input checks of the dynamics: finite vectors of the right shape, an SPD mass."""
from __future__ import annotations

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
import scipy.sparse.linalg as spla

__all__ = ["DENSE_LIMIT", "check_vector", "check_spd_mass"]

# Dense checks (Cholesky, eigvalsh) are exact and cheap below this many free dofs.
DENSE_LIMIT = 1500
#: the smallest pivot of a mass's factorisation, relative to the largest, that is "clearly positive"
PIVOT_RATIO = 1e-14


def check_vector(name: str, value, n: int) -> np.ndarray:
    """Return ``value`` as a float array of shape (n,), or raise ValueError naming it."""
    arr = np.asarray(value, dtype=float)
    if arr.shape != (n,):
        raise ValueError(f"{name} must have shape ({n},), got {arr.shape}")
    bad = ~np.isfinite(arr)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise ValueError(f"{name} contains a non-finite value {float(arr[i])!r} at index {i}")
    return arr


def check_spd_mass(M: sp.csr_matrix) -> None:
    """Raise ValueError unless ``M`` (free-dof block) is symmetric positive definite.

    Cheap checks first (finite, diagonal > 0, symmetric); then a Cholesky factorisation
    for small systems, for large ones a sparse LU without row pivoting (so that its pivots
    are the D of ``L D L^T`` and have the signs of M's eigenvalues, Sylvester's law of
    inertia) with a positive-pivot check (a singular mass fails the LU). Both paths then
    refuse a pivot below :data:`PIVOT_RATIO` times the largest (the Cholesky's are the
    squares of L's diagonal): a mass that is positive definite only to round-off (a
    1e-300 diagonal beside 1) is refused whatever the size of the system.
    """
    if M.shape[0] == 0:
        raise ValueError("M has no free dofs")
    if not np.all(np.isfinite(M.data)):
        raise ValueError("M contains non-finite entries")
    diag = M.diagonal()
    if np.any(diag <= 0):
        i = int(np.flatnonzero(diag <= 0)[0])
        raise ValueError(f"M is not positive definite: diagonal entry M[{i},{i}] = {float(diag[i])!r} <= 0")
    asym = abs(M - M.T).max() if M.nnz else 0.0
    if asym > 1e-10 * abs(M).max():
        raise ValueError(f"M is not symmetric: max |M - M^T| = {asym:.3e}")
    if M.shape[0] <= DENSE_LIMIT:
        try:
            L = np.linalg.cholesky(M.toarray())
        except np.linalg.LinAlgError:
            lam = sla.eigvalsh(M.toarray(), subset_by_index=[0, 0])[0]
            raise ValueError(f"M is not positive definite: smallest eigenvalue {lam:.3e}") from None
        return _clearly_positive(np.diagonal(L) ** 2, "Cholesky")
    try:  # diagonal pivots, a symmetric ordering: U's diagonal is D of M = L D L^T, whose signs are M's inertia
        lu = spla.splu(M.tocsc(), permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                       options={"SymmetricMode": True})
    except RuntimeError as exc:  # "Factor is exactly singular"
        raise ValueError(f"M is singular: {exc}") from None
    _clearly_positive(lu.U.diagonal(), "LU")


def _clearly_positive(piv: np.ndarray, factorisation: str) -> None:
    """Refuse pivots (the D of ``M = L D L^T``) that are not all > 0 and above PIVOT_RATIO x the largest."""
    if np.any(piv <= 0) or np.min(np.abs(piv)) < PIVOT_RATIO * np.max(np.abs(piv)):
        raise ValueError(f"M is not positive definite: {factorisation} pivots not all clearly positive (smallest "
                         f"{np.min(piv):.3e}, largest {np.max(np.abs(piv)):.3e}: below {PIVOT_RATIO:g} x the largest)")
