"""The gmsh steps of the example organs: a body built with gmsh's OpenCASCADE kernel, meshed with
linear tetrahedra of a target size and written as a gmsh file, and the command line that does it.
Shared by ``make_kidney.py`` (beside this file) and ``../nearly_incompressible_organ/make_dome.py``,
which only build their bodies.

Needs gmsh (``pip install gmsh``, or tissuebench's extra ``pip install "tissuebench[mesh]"``).
"""
from __future__ import annotations

import argparse


def mesh_body(path, name: str, build, size: float, quiet: bool = True) -> str:
    """Mesh the volume ``build(occ)`` adds to a new gmsh model ``name`` into ``path`` (.msh, format
    4.1); returns ``path`` as a string.

    ``occ`` is gmsh's OpenCASCADE kernel (``gmsh.model.occ``), in the length unit of the mesh file;
    ``size`` is the target element size in that unit (elements between ``size / 2`` and ``size``,
    Delaunay, then optimised); ``quiet`` keeps gmsh's log off the terminal.
    """
    import gmsh

    gmsh.initialize(["-noenv"] if quiet else [])
    try:
        gmsh.option.setNumber("General.Terminal", 0 if quiet else 1)
        gmsh.model.add(name)
        build(gmsh.model.occ)
        gmsh.model.occ.synchronize()
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


def mesh_main(argv, description: str, mesh, size: float, nodes: str) -> int:
    """The command line ``OUT [--size SIZE]`` of an example organ: ``mesh(OUT, SIZE)`` writes the mesh
    file; ``size`` is the default element size [mm], ``nodes`` about how many nodes it gives."""
    p = argparse.ArgumentParser(description=description)
    p.add_argument("out", help="the mesh file to write (.msh)")
    p.add_argument("--size", type=float, default=size, help=f"target element size [mm] (default {size}: {nodes})")
    args = p.parse_args(argv)
    mesh(args.out, args.size)
    print(f"wrote {args.out}")
    return 0
