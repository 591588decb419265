"""Biharmonic generalised barycentric coordinates of sample elements (wsc paper §2.4, eqs. 17-19).

The paper interpolates the elastic energy density from its values at the sample elements,
``Psi(X) ~ sum_j alpha_j(X) Psi(X_j)`` (eq. 17), with biharmonic generalised barycentric
coordinates ``alpha_j`` (following Tapia et al. 2021), and integrates the interpolant:
``w_j = int alpha_j dOmega`` (eq. 19). We take the sample point ``X_j`` of element j to be
its centroid and compute ``alpha_j`` with libigl's ``biharmonic_coordinates`` -- the
linearly precise coordinates of Wang, Jacobson, Deng et al., "Linear subspace design for
real-time shape deformation" (SIGGRAPH 2015), in libigl's Crouzeix-Raviart form (the
squared-Laplacian energy minimised subject to ``alpha_j = delta_ij`` at the sample points):
they are a partition of unity and reproduce every affine function, so the rule integrates
any energy density that is affine in X exactly.

libigl places point handles on mesh vertices, and a centroid is not one: every sample
tetrahedron is split 1-to-4 at its centroid (:func:`centroid_split`), which adds the
centroids as vertices and leaves the domain and every other element unchanged. The
coordinates are piecewise linear on the split mesh, so ``int alpha_j`` is exact with the
barycentric (lumped) mass of libigl's ``massmatrix``. Cost: one sparse factorisation and
one solve per sample (libigl's ``min_quad_with_fixed``); the paper cube's 2820 samples on
7744 vertices take about 16 s and 1.2 GB (dense coordinates, (vertices + samples) x samples).
"""
from __future__ import annotations

import numpy as np

__all__ = ["centroid_split", "centroid_coordinates", "integrated_coordinates"]


def _check(points, cells, sample):
    V = np.ascontiguousarray(points, dtype=float)
    T = np.ascontiguousarray(cells, dtype=np.int64)
    s = np.asarray(sample, dtype=np.int64).ravel()
    if V.ndim != 2 or V.shape[1] != 3:
        raise ValueError(f"biharmonic coordinates: points must have shape (n, 3), got {V.shape}")
    if T.ndim != 2 or T.shape[1] != 4:
        raise ValueError(f"biharmonic coordinates need tetrahedra (cells of 4 vertices), got cells of shape {T.shape}")
    if len(s) < 4:
        # the squared Laplacian vanishes on affine functions: fewer than 4 points leave them free
        raise ValueError(f"biharmonic coordinates need at least 4 sample elements, got {len(s)}")
    if len(np.unique(s)) != len(s) or s.min() < 0 or s.max() >= len(T):
        raise ValueError(f"sample elements must be distinct indices in 0..{len(T) - 1}")
    return V, T, s


def centroid_split(points, cells, sample):
    """The mesh with every sample tetrahedron split 1-to-4 at its centroid.

    Parameters
    ----------
    points : (n, 3) array
    cells : (n_cells, 4) int array
    sample : (m,) int array
        Distinct cell indices.

    Returns
    -------
    points2 : (n + m, 3) array
        ``points`` followed by the sample centroids (vertex ``n + j`` is sample j's centroid).
    cells2 : (n_cells + 3 m, 4) int array
        The other cells, then the four sub-tetrahedra of each sample (same orientation).
    """
    V, T, s = _check(points, cells, sample)
    n, m = len(V), len(s)
    centroid = np.arange(n, n + m)
    keep = np.ones(len(T), dtype=bool)
    keep[s] = False
    sub = []
    for i in range(4):  # vertex i replaced by the centroid: orientation kept
        t = T[s].copy()
        t[:, i] = centroid
        sub.append(t)
    return np.vstack([V, V[T[s]].mean(axis=1)]), np.vstack([T[keep]] + sub)


def centroid_coordinates(points, cells, sample):
    """Biharmonic coordinates ``alpha_j`` of the sample centroids on the split mesh.

    Returns
    -------
    alpha : (n + m, m) array
        ``alpha[v, j]``: coordinate j at vertex v of the split mesh (piecewise linear).
    points2, cells2 : the split mesh (:func:`centroid_split`).

    Raises
    ------
    ValueError
        The coordinates are not finite (degenerate samples, e.g. all on a plane).
    """
    import igl  # libigl's Python binding (pip "libigl")

    V2, T2 = centroid_split(points, cells, sample)
    n = len(np.asarray(points))
    handles = [[int(i)] for i in range(n, len(V2))]
    alpha = np.asarray(igl.biharmonic_coordinates(V2, T2, handles, 2))
    if alpha.shape != (len(V2), len(handles)) or not np.all(np.isfinite(alpha)):
        raise ValueError(f"biharmonic coordinates of {len(handles)} sample centroids are not finite (samples "
                         "coplanar or the mesh degenerate?)")
    return alpha, V2, T2


def integrated_coordinates(points, cells, sample) -> tuple[np.ndarray, dict]:
    """``w_j = int alpha_j dOmega`` of the sample centroids (eq. 19) and construction checks.

    Returns
    -------
    w : (m,) array [volume]
        Sums to the mesh volume; may hold negative entries (the coordinates are not positive).
    checks : dict
        ``partition_of_unity`` and ``affine_residual`` (max deviations of ``sum_j alpha_j``
        from 1 and of ``sum_j alpha_j X_j`` from X, relative to the mesh size).
    """
    import igl

    alpha, V2, T2 = centroid_coordinates(points, cells, sample)
    mass = igl.massmatrix(V2, T2, igl.MASSMATRIX_TYPE_BARYCENTRIC).diagonal()
    n = len(np.asarray(points))
    size = float(np.ptp(V2, axis=0).max())
    checks = {"partition_of_unity": float(np.abs(alpha.sum(axis=1) - 1.0).max()),
              "affine_residual": float(np.abs(alpha @ V2[n:] - V2).max() / size)}
    return alpha.T @ mass, checks
