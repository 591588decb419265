"""The states of a reference run a path training and a path evaluation read: the converged states
(:func:`reference_states`, refusing a run without one) and the ones a path training keeps
(:func:`training_indices`). Below the training (:mod:`.training`), the range of a path
(:mod:`.path_range`) and the checks of a spec's values (:mod:`.limits`), which all read them.
"""
from __future__ import annotations

import numpy as np

__all__ = ["require_converged", "reference_states", "training_indices"]


def require_converged(ref) -> None:
    """Refuse a reference run that converged at no step (its only state is the initial one): a
    RuntimeError naming the case and saying why the reference stopped, not a shape error later."""
    if len(ref.displacement) < 2:
        variant = f" (variant {ref.variant})" if ref.variant else ""
        raise RuntimeError(f"case {ref.case!r}{variant}: the reference run ({ref.backend}) converged at no step, so "
                           f"there is no state to learn from or measure against: {ref.status}: {ref.message[:400]}")


def reference_states(ref) -> tuple[np.ndarray, np.ndarray]:
    """``(states (n_dof, k), steps (k,))`` of a reference result without its initial state
    (RuntimeError naming the case when it has none, :func:`require_converged`)."""
    require_converged(ref)
    U = ref.displacement[1:].reshape(len(ref.displacement) - 1, -1).T
    return np.ascontiguousarray(U), np.asarray(ref.steps[1:], float)


def training_indices(n: int, every) -> np.ndarray:
    """The states a path training keeps of a path of ``n`` states (the initial one included):
    every ``every``-th, counted back from the last (always kept)."""
    return np.arange(n)[::-1][::int(every)][::-1]
