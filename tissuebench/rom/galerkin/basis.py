"""The POD basis of a trajectory training and the training states the hyper-reduction fits.

The snapshots are the displacements of the free dofs of every training run (one column per
stored step, every run of ``Training.trajectories``); with ``velocities`` the velocity
snapshots join them, scaled by ``|U|_F / |V|_F`` so that neither set dominates the POD by its
unit. The basis comes from :func:`~tissuebench.rom.pod.pod_basis` (euclidean or mass inner
product); the initial state and the training states are projected in the same inner product.
"""
from __future__ import annotations

import numpy as np

from ..pod import PodBasis, pod_basis

__all__ = ["snapshot_basis", "training_states"]


def snapshot_basis(training, free, options) -> tuple[PodBasis, np.ndarray, dict]:
    """``(pod, projector (r, n_free), info)`` of a trajectory training (module docstring).

    ``options``: ``n_modes``, ``energy``, ``inner`` ("euclidean" | "mass"), ``velocities`` (bool).
    """
    U = training.snapshots[free]
    S = U
    with_v = options["velocities"] and training.velocities is not None and np.any(training.velocities[free])
    if with_v:
        Vs = training.velocities[free]
        S = np.hstack([U, (np.linalg.norm(U) / np.linalg.norm(Vs)) * Vs])
    W = training.system.M_ff if options["inner"] == "mass" else None
    pod = pod_basis(S, options["energy"], options["n_modes"], W)
    V = pod.modes
    projector = np.ascontiguousarray(V.T if W is None else (W @ V).T)  # V is W-orthonormal
    residual = U - V @ (projector @ U)
    runs = np.unique(training.trajectories) if training.trajectories is not None else np.zeros(1)
    info = {"n_modes": int(V.shape[1]), "energy_captured": pod.energy_captured, "rank": pod.rank,
            "basis_message": pod.message, "singular_values": pod.singular_values[:60].tolist(),
            "snapshots": int(U.shape[1]), "runs": int(len(runs)), "with_velocities": bool(with_v),
            "training_projection_error": float(np.linalg.norm(residual) / max(np.linalg.norm(U), 1e-300))}
    return pod, projector, info


def training_states(training, free, fixed, projector, prescribed: bool, count: int) -> list:
    """At most ``count`` training states, evenly spaced through the snapshot columns, as
    ``(q (r,), u_c (n_c,) or None)`` (``q`` the projection of the free part, ``u_c`` the
    prescribed values of the sorted fixed dofs)."""
    S = training.snapshots
    cols = np.unique(np.linspace(0, S.shape[1] - 1, min(count, S.shape[1])).round().astype(int))
    return [(projector @ S[free, c], S[fixed, c].copy() if prescribed else None) for c in cols]
