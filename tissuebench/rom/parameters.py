"""The check of a step's parameters ``mu`` (:func:`check_parameters`): below the method contract
(:mod:`.base`, which exports it) and the online kernels (:mod:`.online`), which both read it."""
from __future__ import annotations

from collections.abc import Mapping

import numpy as np

__all__ = ["check_parameters"]


def check_parameters(mu, required: tuple, name: str) -> dict:
    """``mu`` as a dict with finite numeric ``required`` keys; ValueError naming the key otherwise."""
    if not isinstance(mu, Mapping):
        raise TypeError(f"{name}.step: mu must be a mapping of parameters, got {type(mu).__name__}")
    out = dict(mu)
    for key in required:
        if key not in out:
            raise ValueError(f"{name}.step: parameter {key!r} missing from mu = {out}")
        v = out[key]
        if isinstance(v, bool) or not isinstance(v, (int, float, np.floating, np.integer)) or not np.isfinite(v):
            raise ValueError(f"{name}.step: mu[{key!r}] = {v!r} is not a finite number")
    return out
