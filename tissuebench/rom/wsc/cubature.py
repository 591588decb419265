"""Cubature rules for the reduced internal force (wsc paper §2.4; An, Kim, James 2008).

A rule is a set of sample elements ``e`` with weights ``w_e`` multiplying the element
force vectors: ``f_q(q) ~ sum_e w_e U_e^T f_e(U_e q)`` (all elements with ``w_e = 1`` is
the exact reduced force ``U^T f_int(U q)``). The snapshot-free rules share the sample
elements -- approximately equidistant, by furthest-point sampling of the element centroids
-- and the weight ``w_j = int alpha_j dOmega / V_j`` (eq. 19, divided by the sample's volume
because our weight multiplies its element force, not a force density); they differ in the
weight functions ``alpha_j``:

* :func:`full_cubature`: every element, unit weights (the exact reference).
* :func:`bgbc_cubature`, the paper's scheme: ``alpha_j`` the biharmonic generalised
  barycentric coordinates of the sample centroids (libigl, :mod:`.biharmonic`), linearly
  precise, so the rule integrates every affine energy density exactly. Its weights may be
  negative (the coordinates are not positive); ``info["negative_weights"]`` counts them.
* :func:`rbf_cubature` (ours, the construction before the paper's was available here):
  ``alpha_j`` normalised radial basis functions, the interpolating Franke-Little kernel of
  :mod:`.weights` with support ``cubature_support`` times the covering radius of the
  samples (a positive partition of unity, 1 at its own sample; constants integrate exactly,
  affine densities do not).
* :func:`nnls_cubature`: elements and non-negative weights fitted to training reduced
  forces (scipy.optimize.nnls), see its docstring.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from .biharmonic import integrated_coordinates
from .handles import furthest_point_sampling
from .weights import skinning_weights

__all__ = ["Cubature", "full_cubature", "bgbc_cubature", "rbf_cubature", "cell_centroids"]


@dataclass
class Cubature:
    """Sample elements and the weights of their element force vectors.

    Attributes
    ----------
    cells : (m,) int array
    weights : (m,) array
        Finite, not zero; > 0 except for the paper's BGBC rule.
    scheme : str
    info : dict
        Construction details (support radius, fit errors, timings).
    """

    cells: np.ndarray
    weights: np.ndarray
    scheme: str
    info: dict = field(default_factory=dict)

    def __post_init__(self):
        self.cells = np.asarray(self.cells, dtype=np.int64)
        self.weights = np.asarray(self.weights, dtype=float)
        if self.cells.shape != self.weights.shape or not len(self.cells):
            raise ValueError(f"cubature: {len(self.cells)} cells and {len(self.weights)} weights (need >= 1, equal)")
        if not np.all(np.isfinite(self.weights)) or np.any(self.weights == 0):
            raise ValueError("cubature: weights must be finite and not zero")

    @property
    def size(self) -> int:
        return len(self.cells)


def cell_centroids(points, cells) -> np.ndarray:
    """Vertex-average centroid of every cell, shape (n_cells, 3)."""
    return np.asarray(points, float)[np.asarray(cells)].mean(axis=1)


def full_cubature(n_cells: int) -> Cubature:
    """Every element with weight 1."""
    return Cubature(np.arange(n_cells), np.ones(n_cells), "full")


def bgbc_cubature(points, cells, volumes, count: int, seed: int = 0) -> Cubature:
    """The paper's cubature: FPS sample elements, biharmonic coordinates of their centroids, integrated.

    Parameters
    ----------
    points : (n, 3) array
        Mesh vertices.
    cells : (n_cells, 4) int array
        Tetrahedra.
    volumes : (n_cells,) array
        Reference volumes of all elements (the backend's).
    count : int
        Number of sample elements (the cubature budget), 4 <= count <= n_cells.
    seed : int
        Seed of the first sample.
    """
    tic = time.perf_counter()
    volumes = np.asarray(volumes, dtype=float)
    centroids = cell_centroids(points, cells)
    fps = furthest_point_sampling(centroids, count, seed)
    if count == len(volumes):  # every element is a sample: the exact rule
        return Cubature(fps.indices, np.ones(count), "bgbc", {"offline_s": time.perf_counter() - tic,
                                                                "volume_check": 1.0, "negative_weights": 0})
    integral, checks = integrated_coordinates(points, cells, fps.indices)  # int alpha_j dOmega
    w = integral / volumes[fps.indices]
    info = {"covering_radius": fps.covering_radius, "offline_s": time.perf_counter() - tic,
            "volume_check": float(integral.sum() / volumes.sum()), "negative_weights": int(np.sum(w < 0)),
            "min_weight": float(w.min()), **checks}
    return Cubature(fps.indices, w, "bgbc", info)


def rbf_cubature(centroids, volumes, count: int, seed: int = 0, support: float = 2.0) -> Cubature:
    """Ours: FPS sample elements, normalised RBF weight functions, integrated (see the module docstring).

    Parameters
    ----------
    centroids : (n_cells, 3) array
    volumes : (n_cells,) array
        Reference volumes of all elements.
    count : int
        Number of sample elements (the cubature budget), 1 <= count <= n_cells.
    seed : int
        Seed of the first sample.
    support : float
        Radius of the weight functions in units of the samples' covering radius (> 1).
    """
    tic = time.perf_counter()
    volumes = np.asarray(volumes, dtype=float)
    fps = furthest_point_sampling(centroids, count, seed)
    if fps.covering_radius == 0:  # every element is a sample: the exact rule
        return Cubature(fps.indices, np.ones(count), "rbf", {"support_radius": 0.0, "covering_radius": 0.0,
                                                               "offline_s": time.perf_counter() - tic,
                                                               "volume_check": 1.0})
    radius = support * fps.covering_radius
    alpha = skinning_weights(centroids, np.asarray(centroids)[fps.indices], radius)  # (n_cells, count)
    integral = np.asarray(alpha.T @ volumes).ravel()  # int alpha_j dOmega
    w = integral / volumes[fps.indices]
    info = {"support_radius": radius, "covering_radius": fps.covering_radius, "offline_s": time.perf_counter() - tic,
            "volume_check": float(integral.sum() / volumes.sum())}
    return Cubature(fps.indices, w, "rbf", info)
