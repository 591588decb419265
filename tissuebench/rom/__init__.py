"""Reduced-order models: one module per method family, one offline/online contract (:mod:`.base`)."""
from .base import (METHODS, STEP_STATUSES, OnlineModel, RomMethod, StepResult, Training, check_parameters,
                   make_method, register)
from . import anm, anm_interp, anm_pod, direct, interpolation, pgd, pod  # noqa: F401  (registers the methods)

__all__ = ["METHODS", "STEP_STATUSES", "OnlineModel", "RomMethod", "StepResult", "Training", "check_parameters",
           "make_method", "register"]
