"""Reference runs of catalogue scenes: the plan ("model only what a scene requires"), the
runner ``solve(scene)``, and the content-hashed on-disk cache every sweep reuses.

This package sits above :mod:`tissuebench.cases` and :mod:`tissuebench.refsolvers`: the FE
kernel knows nothing of scenes, the scenes know nothing of solvers.
"""
from .plan import EXPLICIT_INTEGRATORS, ModelPlan, plan_for
from .result import ReferenceResult, dynamics_output
from .runner import dynamics_system, solve
from .cache import CACHE_ENV, cached_solve, reference_key
from .memo import MEMO
from .step_timing import cached_dynamics_system, reference_step_seconds

__all__ = ["EXPLICIT_INTEGRATORS", "ModelPlan", "plan_for", "ReferenceResult", "dynamics_output", "dynamics_system",
           "solve", "CACHE_ENV", "cached_solve", "reference_key", "MEMO", "cached_dynamics_system",
           "reference_step_seconds"]
