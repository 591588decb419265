"""The reference layer: every full-model (reference) solve of a catalogue scene and its timing.

It owns the plan ("model only what a scene requires", :mod:`.plan`), the runner
``solve(scene)`` (:mod:`.runner`, the 1D models in :mod:`.line`), the content-hashed on-disk
cache every sweep reuses (:mod:`.cache`, :mod:`.entry`, :mod:`.location`) and the provenance
its keys hold (:mod:`.provenance`), the full step the protocol times beside every reduced
model (:mod:`.step_timing`), the linear FE of every cut length of an incision (:mod:`.cut`),
our values of the external anchors (:mod:`.anchors`), the backend comparison
(:mod:`.backend_comparison`), and the one in-process memo of what a process's units share
(:mod:`.memo`).

It sits between :mod:`tissuebench.cases` and :mod:`tissuebench.rom` (docs/explanation/architecture.md; checked
by ``tests/test_layers.py``): the FE kernel knows nothing of scenes, the scenes know nothing of
solvers, and no reference imports a reduced model or the sweep harness (what it needs of
them, a cutting model's incision strip, is passed in).
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
