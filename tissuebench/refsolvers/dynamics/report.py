"""The outcome of one step of a time integrator (:class:`StepReport`): the contract below the
integrators (:mod:`.base`) and the Newton iterations of their steps (:mod:`.step_newton`), which
both report through it."""
from __future__ import annotations

from dataclasses import dataclass, field

__all__ = ["StepReport"]


@dataclass
class StepReport:
    """Outcome of one step: ``converged`` False means the state was not advanced;
    ``within_tolerance`` False, that it was advanced after a fixed Newton budget whose last
    residual was still above the tolerance (``message`` says by how much)."""

    converged: bool = True
    iterations: int = 0
    message: str = ""
    residuals: list = field(default_factory=list)
    within_tolerance: bool = True
