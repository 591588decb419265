"""Mesh builders: structured boxes (tetrahedra or hexahedra) and netgen boxes."""
from __future__ import annotations

import numpy as np

from ..refsolvers.mesh import Mesh

# Six tetrahedra per hexahedron around the 0-6 diagonal (conforming across cells).
_HEX_TO_6_TETS = np.array([[0, 1, 2, 6], [0, 2, 3, 6], [0, 3, 7, 6], [0, 7, 4, 6], [0, 4, 5, 6], [0, 5, 1, 6]])


def box_mesh(lengths=(1.0, 1.0, 1.0), divisions=(1, 1, 1), cell_type="tetra", origin=(0.0, 0.0, 0.0),
             jitter=0.0, seed=0) -> Mesh:
    """Structured mesh of the box ``origin + [0, Lx] x [0, Ly] x [0, Lz]``.

    Parameters
    ----------
    lengths : (3,) floats
        Box edge lengths.
    divisions : (3,) ints
        Number of cells per direction.
    cell_type : {"tetra", "hexahedron"}
        Hexahedra, or six tetrahedra per hexahedron.
    jitter : float
        Random displacement of interior vertices, as a fraction (< 0.5) of the local
        cell size, to build distorted meshes for patch tests (seeded by ``seed``).
    """
    L = np.asarray(lengths, float)
    n = np.asarray(divisions, int)
    if L.shape != (3,) or np.any(L <= 0) or not np.all(np.isfinite(L)):
        raise ValueError(f"lengths must be three finite numbers > 0, got {lengths!r}")
    if n.shape != (3,) or np.any(n < 1):
        raise ValueError(f"divisions must be three integers >= 1, got {divisions!r}")
    if not 0 <= jitter < 0.5:
        raise ValueError(f"jitter must lie in [0, 0.5), got {jitter!r}")
    axes = [np.linspace(0.0, L[d], n[d] + 1) for d in range(3)]
    X = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    if jitter:
        interior = np.all((X > 1e-12 * L) & (X < L * (1 - 1e-12)), axis=1)
        rng = np.random.default_rng(seed)
        X[interior] += jitter * rng.uniform(-1, 1, (interior.sum(), 3)) * (L / n)
    I, J, K = (a.ravel() for a in np.meshgrid(*[np.arange(k) for k in n], indexing="ij"))
    vid = lambda i, j, k: (i * (n[1] + 1) + j) * (n[2] + 1) + k  # noqa: E731
    hexes = np.stack([vid(I, J, K), vid(I + 1, J, K), vid(I + 1, J + 1, K), vid(I, J + 1, K),
                      vid(I, J, K + 1), vid(I + 1, J, K + 1), vid(I + 1, J + 1, K + 1), vid(I, J + 1, K + 1)], 1)
    points = X + np.asarray(origin, float)
    if cell_type == "hexahedron":
        return Mesh(points, hexes, "hexahedron")
    if cell_type == "tetra":
        return Mesh(points, hexes[:, _HEX_TO_6_TETS].reshape(-1, 4), "tetra")
    raise ValueError(f"cell_type={cell_type!r} is not one of ['hexahedron', 'tetra']")


def netgen_box_mesh(lengths=(1.0, 1.0, 1.0), maxh=0.1, origin=(0.0, 0.0, 0.0)) -> Mesh:
    """Unstructured tetrahedral mesh of a box by netgen (OpenCASCADE geometry)."""
    L = np.asarray(lengths, float)
    if L.shape != (3,) or np.any(L <= 0):
        raise ValueError(f"lengths must be three numbers > 0, got {lengths!r}")
    if not maxh > 0:
        raise ValueError(f"maxh must be > 0, got {maxh!r}")
    from netgen.occ import Box, OCCGeometry, Pnt

    o = np.asarray(origin, float)
    geo = OCCGeometry(Box(Pnt(*o), Pnt(*(o + L))))
    ngmesh = geo.GenerateMesh(maxh=maxh, quad_dominated=False)
    points = np.array([p.p for p in ngmesh.Points()])
    cells = np.array([[v.nr - 1 for v in el.vertices] for el in ngmesh.Elements3D()], dtype=np.int64)
    return Mesh(points, cells, "tetra")
