"""A nearly incompressible organ: a half ellipsoid (a dome) meshed with gmsh, in millimetres.

Semi-axes 60, 60 and 120 mm (x, y, z), the flat base on z = 0. Linear tetrahedra, written as
a gmsh file::

    python make_dome.py dome.msh              # ~5k nodes (mesh size 5.6 mm)
    python make_dome.py dome.msh --size 24    # a coarse one (the tests')

The scene ``dome.toml`` clamps the base and pushes the apex sideways with 2 N on a 5 mm patch.
"""
from __future__ import annotations

import argparse
import sys


def dome_mesh(path: str, size: float = 5.6, semi_axes=(60.0, 60.0, 120.0), quiet: bool = True) -> str:
    """Mesh the half ellipsoid with target element size ``size`` [mm] into ``path`` (.msh); returns it."""
    import gmsh

    a, b, c = semi_axes
    gmsh.initialize(["-noenv"] if quiet else [])
    try:
        gmsh.option.setNumber("General.Terminal", 0 if quiet else 1)
        gmsh.model.add("dome")
        occ = gmsh.model.occ
        body = occ.addSphere(0.0, 0.0, 0.0, 1.0)
        occ.dilate([(3, body)], 0.0, 0.0, 0.0, a, b, c)
        lower = occ.addBox(-2 * a, -2 * b, -2 * c, 4 * a, 4 * b, 2 * c)
        occ.cut([(3, body)], [(3, lower)])
        occ.synchronize()
        gmsh.option.setNumber("Mesh.MeshSizeMin", 0.5 * size)
        gmsh.option.setNumber("Mesh.MeshSizeMax", size)
        gmsh.option.setNumber("Mesh.Algorithm3D", 1)  # Delaunay
        gmsh.option.setNumber("Mesh.Optimize", 1)
        gmsh.option.setNumber("Mesh.MshFileVersion", 4.1)
        gmsh.model.mesh.generate(3)
        gmsh.write(str(path))
    finally:
        gmsh.finalize()
    return str(path)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("out", help="the mesh file to write (.msh)")
    p.add_argument("--size", type=float, default=5.6, help="target element size [mm] (default 5.6: ~5k nodes)")
    args = p.parse_args(argv)
    dome_mesh(args.out, args.size)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
