"""A kidney-like organ meshed with gmsh: the mesh file of the tutorial "Bring your own organ"
(docs/tutorials/own-organ.md).

An ellipsoid of 110 x 60 x 50 mm (semi-axes 55, 30, 25 mm along x, y, z) with a notch on its
medial side (+y), the hilum, where the renal vessels enter and the organ is held. Linear
tetrahedra, written as a gmsh file in millimetres::

    python make_kidney.py kidney.msh            # 4534 nodes, 21727 tetrahedra (mesh size 3.3 mm)
    python make_kidney.py kidney.msh --size 9   # a coarse one (396 nodes: the test's)

The gmsh steps after the body (element sizes, algorithm, the file) and the command line are
``gmsh_body.py``'s, beside this file. Needs gmsh (``pip install gmsh``, or tissuebench's extra
``pip install "tissuebench[mesh]"``).
"""
from __future__ import annotations

import sys

from gmsh_body import mesh_body, mesh_main  # beside this file: the gmsh steps the example organs share


def kidney_body(occ) -> None:
    """The ellipsoid with the hilum cut out, in gmsh's OpenCASCADE kernel ``occ`` (millimetres)."""
    body = occ.addSphere(0.0, 0.0, 0.0, 1.0)
    occ.dilate([(3, body)], 0.0, 0.0, 0.0, 55.0, 30.0, 25.0)
    hilum = occ.addCylinder(0.0, 22.0, -30.0, 0.0, 0.0, 60.0, 11.0)  # along z, centred on the medial side
    occ.cut([(3, body)], [(3, hilum)])


def kidney_mesh(path: str, size: float = 3.3, quiet: bool = True) -> str:
    """Mesh the kidney with target element size ``size`` [mm] into ``path`` (.msh); returns it."""
    return mesh_body(path, "kidney", kidney_body, size, quiet)


def main(argv=None) -> int:
    return mesh_main(argv, __doc__.splitlines()[0], kidney_mesh, 3.3, "~4.5k nodes")


if __name__ == "__main__":
    sys.exit(main())
