"""The paper's basis interpolations as methods of their own (anm-pod-large-deformations §5):
``podi`` (§5.2) and ``grassmann`` (§5.1), each :class:`~.anm_interp.AnmPodInterp` with its
basis interpolation fixed; the alignment, the interpolated tensors and the online step are
that module's.
"""
from __future__ import annotations

from .anm_interp import AnmPodInterp
from .base import register

__all__ = ["Podi", "Grassmann"]


@register
class Podi(AnmPodInterp):
    """PODI (paper §5.2): stored POD bases aligned mode by mode and interpolated piecewise
    linearly between load positions, with the reduced SVK tensors (the f_nl terms)
    interpolated alike; the reduced ANM series solves the state. :class:`AnmPodInterp` with
    ``basis_interpolation="podi"``, ``align="modes"`` (the more accurate pairing measured)."""

    name = "podi"

    def __init__(self, n_modes: int | None = None, order: int = 6, eps: float = 1e-4, max_segments: int = 100,
                 align: str = "modes"):
        super().__init__(n_modes, order, eps, "podi", max_segments, align)


@register
class Grassmann(AnmPodInterp):
    """Grassmann interpolation (paper §5.1, Amsallem-Farhat log/exp maps about the nearest
    stored basis) of the POD basis between load positions, tensors interpolated in aligned
    coordinates; :class:`AnmPodInterp` with ``basis_interpolation="grassmann"``."""

    name = "grassmann"

    def __init__(self, n_modes: int | None = None, order: int = 6, eps: float = 1e-4, max_segments: int = 100,
                 align: str = "modes"):
        super().__init__(n_modes, order, eps, "grassmann", max_segments, align)
