"""A nearly incompressible organ: a half ellipsoid (a dome) meshed with gmsh, in millimetres.

Semi-axes 60, 60 and 120 mm (x, y, z), the flat base on z = 0. Linear tetrahedra, written as
a gmsh file::

    python make_dome.py dome.msh              # ~5k nodes (mesh size 5.6 mm)
    python make_dome.py dome.msh --size 24    # a coarse one (the tests')

The scene ``dome.toml`` clamps the base and pushes the apex sideways with 2 N on a 5 mm patch.
"""
from __future__ import annotations

import sys
from pathlib import Path

# the gmsh steps the example organs share: examples/bring_your_own_organ/gmsh_body.py
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bring_your_own_organ"))
from gmsh_body import mesh_body, mesh_main  # noqa: E402


def dome_mesh(path: str, size: float = 5.6, semi_axes=(60.0, 60.0, 120.0), quiet: bool = True) -> str:
    """Mesh the half ellipsoid with target element size ``size`` [mm] into ``path`` (.msh); returns it."""
    a, b, c = semi_axes

    def dome(occ) -> None:
        body = occ.addSphere(0.0, 0.0, 0.0, 1.0)
        occ.dilate([(3, body)], 0.0, 0.0, 0.0, a, b, c)
        lower = occ.addBox(-2 * a, -2 * b, -2 * c, 4 * a, 4 * b, 2 * c)
        occ.cut([(3, body)], [(3, lower)])

    return mesh_body(path, "dome", dome, size, quiet)


def main(argv=None) -> int:
    return mesh_main(argv, __doc__.splitlines()[0], dome_mesh, 5.6, "~5k nodes")


if __name__ == "__main__":
    sys.exit(main())
