"""What practitioners run instead of a ROM: full FE models made cheaper, under the ROM contract.

* ``linear_fe`` (:mod:`.linear`): linear elasticity on the scene's mesh, factorised once; the
  haptic step is a back-substitution, or with ``condensed = true`` a small dense product of the
  precomputed compliance (Bro-Nielsen and Cotin 1996).
* ``corotational_fe`` (:mod:`.corotational`): corotational linear FEM (per-element rotation by
  polar decomposition, SOFA's "polar" tetrahedra), Newton load stepping or the scene's integrator.
* ``coarse_fe`` (:mod:`.coarse`): the full, linear or corotational model on a coarser mesh of the
  same body, interpolated to the scene's mesh.

Shared pieces: :mod:`.common` (scene, loads, the map to the fine mesh, outputs) and
:mod:`.stepping` (Newton along a path, an integrator along a trajectory). They are measured
like every ROM (same protocol, same reference); the fidelity ladder of a sweep
(:mod:`tissuebench.studies.ladder`) reads their errors along the path.
"""
from . import coarse, corotational, linear  # noqa: F401  (registers the methods)
from .coarse import CoarseFe
from .corotational import CorotationalFe
from .linear import LinearFe

__all__ = ["LinearFe", "CorotationalFe", "CoarseFe"]
