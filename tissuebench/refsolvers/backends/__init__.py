"""Finite-element backends (scikit-fem, NGSolve) behind :class:`~.base.Backend`."""
from .base import BACKENDS, Backend, make_backend

__all__ = ["BACKENDS", "Backend", "make_backend"]
