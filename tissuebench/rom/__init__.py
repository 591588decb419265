"""Reduced-order models: one module per method family, one offline/online contract (:mod:`.base`),
one registry (:mod:`.registry`) that the methods of other packages join when it is first read
(:mod:`.plugins`)."""
from .base import (METHODS, MODEL_KINDS, STEP_STATUSES, Applies, LinearReconstruction, OnlineModel, RomMethod,
                   StepResult, Training, check_parameters, make_method, method_class, register)
from . import (anm, anm_interp, anm_pod, baselines, interpolation, pgd, pgd_direct, pod,  # noqa: F401  (registers
               subspace_interp, wsc)
from . import fe_baselines  # noqa: F401,E402  (registers linear_fe, corotational_fe, coarse_fe)
from . import galerkin  # noqa: F401,E402  (registers pod_galerkin)
from .elements import element_kernel, galerkin_model  # noqa: E402  (a training's element operators, public)
from .plugins import load_entry_points, load_source  # noqa: E402

# the installed plugins join at the first read, after every shipped method: a clash names the shipped one
METHODS.arm(load_entry_points)
# a "module:Class" name is imported and registered by the plugins' loader (the registry sits below them)
METHODS.arm_sources(load_source)

__all__ = ["METHODS", "MODEL_KINDS", "STEP_STATUSES", "Applies", "LinearReconstruction", "OnlineModel", "RomMethod",
           "StepResult", "Training", "check_parameters", "make_method", "method_class", "register", "element_kernel",
           "galerkin_model"]
