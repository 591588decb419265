"""The names the whole package and its command line choose from, written once.

Dependency-free so that the command line can offer them without importing a solver.
"""
from __future__ import annotations

__all__ = ["BACKEND_NAMES", "RESOLUTIONS"]

#: the finite-element backends (:mod:`tissuebench.refsolvers.backends`), the default first
BACKEND_NAMES = ("skfem", "ngsolve")
#: mesh resolutions of every catalogue case: ``ci`` (seconds, CI) and ``paper`` (the papers' meshes)
RESOLUTIONS = ("ci", "paper")
