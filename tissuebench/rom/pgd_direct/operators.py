"""Offline inputs of the direct integrator read from a :class:`~tissuebench.rom.base.Training`.

* :func:`step_operators`: ``M, K, C, f`` on the free dofs from the training's
  :class:`~tissuebench.refsolvers.dynamics.SecondOrderSystem` (the load must be one vector
  times the history, ``f_ext(t) = history(t) f``, a dead load).
* :func:`state_bases`: one POD basis per state field (displacements, velocities and,
  for HHT, accelerations; mass-orthonormal, so that projecting a state is the Galerkin
  projection in the kinetic-energy norm) and the training values of every reduced
  coordinate, from which :func:`~tissuebench.rom.pgd_direct.meshes.parameter_domain` takes
  the intervals of the vademecum.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from ..pod import pod_basis
from .schemes import StepOperators

__all__ = ["StateBases", "load_factors", "state_bases", "step_operators"]


def load_factors(training) -> np.ndarray:
    """Load factor of every training snapshot (``parameters[k]["load_factor"]``, else ``history(time)``)."""
    params = training.parameters or []
    if params and all("load_factor" in p for p in params):
        return training.parameter_values("load_factor")
    if training.history is not None and params and all("time" in p for p in params):
        return np.array([float(training.history(t)) for t in training.parameter_values("time")])
    raise ValueError("training.parameters need 'load_factor' (or 'time' with a history) for every snapshot")


def _load_vector(system, training, lams) -> np.ndarray:
    """f with ``f_ext(t, 0) = history(t) f``, read at the snapshot of largest |load factor|."""
    times = training.parameter_values("time")
    k = int(np.argmax(np.abs(lams)))
    if lams[k] == 0.0:
        raise ValueError("training: the load factor is zero at every snapshot; the load vector is undefined")
    zero = np.zeros(len(system.free))
    f = system.f_ext(times[k], zero) / lams[k]
    if system.load_tangent is not None and system.load_tangent(times[k], system.expand(zero)) is not None:
        raise ValueError("the direct integrator needs a dead load (the training system has a follower load)")
    j = int(np.argmin(np.abs(np.abs(lams) - 0.5 * abs(lams[k]))))  # a second time: is the load affine?
    if lams[j] != 0.0 and not np.allclose(system.f_ext(times[j], zero), lams[j] * f,
                                          rtol=1e-10, atol=1e-12 * np.abs(f).max()):
        raise ValueError("the training load is not one vector times the load factor (f_ext(t) != history(t) f)")
    return f


def step_operators(training, mass: str = "consistent") -> StepOperators:
    """``M a + C v + f_int(u) = lam f`` on the free dofs of ``training.system``.

    Parameters
    ----------
    training : Training
        Needs ``system`` (SecondOrderSystem) and ``parameters`` with ``time`` (and
        ``load_factor`` or a ``history``). ``backend`` (FE scenes) decides linearity by
        its material; otherwise ``system.linear``.
    mass : {"consistent", "lumped"}
        The system's mass or its row-sum lumped diagonal.
    """
    system = training.system
    if system is None or not hasattr(system, "M_ff"):
        raise ValueError("direct integrator: training.system must be a SecondOrderSystem")
    if mass not in ("consistent", "lumped"):
        raise ValueError(f"mass = {mass!r}; valid: ['consistent', 'lumped']")
    M = sp.csr_matrix(system.M_ff)
    if mass == "lumped":
        M = sp.diags(np.asarray(M.sum(axis=1)).ravel(), format="csr")
    be = training.backend
    linear = bool(system.linear) or (be is not None and bool(be.problem.material.is_linear))
    f = _load_vector(system, training, load_factors(training))
    return StepOperators(M, sp.csr_matrix(system.K0_ff), f, system.C_ff,
                         None if linear else system.f_int)


@dataclass
class StateBases:
    """Mass-orthonormal POD bases of the state fields and the training coordinates.

    Attributes
    ----------
    bases : dict
        ``"u"`` (and ``"v"``) -> (n_free, m_k) basis, ``Phi^T M Phi = I``.
    coordinates : dict
        Same keys -> (m_k, n_snap) reduced coordinates of the training snapshots.
    energy : dict
        Same keys -> fraction of the snapshot energy (M-norm) captured.
    """

    bases: dict
    coordinates: dict
    energy: dict

    def project(self, M, field: str, x) -> np.ndarray:
        """Reduced coordinates ``Phi^T M x`` of a free-dof vector (M-orthogonal projection)."""
        return self.bases[field].T @ (M @ x)

    def rotate(self, field: str, V) -> None:
        """Replace basis ``field`` by ``Phi V`` (V orthogonal): same space, rotated coordinates."""
        self.bases[field] = self.bases[field] @ V
        self.coordinates[field] = V.T @ self.coordinates[field]


def state_bases(training, ops: StepOperators, fields, n_modes: int, need_velocities: bool = False) -> StateBases:
    """POD bases (mass inner product) of the fields a scheme needs.

    Parameters
    ----------
    training : Training
        ``snapshots`` (displacements) and ``velocities`` (n_dof, n_snap).
    ops : StepOperators
    fields : iterable of {"u", "v"}
        Bases to build.
    n_modes : int
        Modes per field (fewer when the snapshots have a lower rank; reported).
    need_velocities : bool
        Refuse a training without velocities even when no velocity basis is built.
    """
    if training.snapshots is None:
        raise ValueError("direct integrator: training.snapshots (displacements) are required")
    free = np.asarray(training.free_dofs)
    U = training.snapshots[free]
    need_v = "v" in fields or need_velocities
    if need_v and training.velocities is None:
        raise ValueError("direct integrator: training.velocities are required for this inner integrator")
    V = training.velocities[free] if training.velocities is not None else None
    data = {"u": U, "v": V}
    bases, coords, energy = {}, {}, {}
    for name in dict.fromkeys(fields):
        pod = pod_basis(data[name], n_modes=n_modes, inner=ops.M)
        bases[name] = pod.modes
        coords[name] = pod.modes.T @ (ops.M @ data[name])
        energy[name] = pod.energy_captured
    return StateBases(bases, coords, energy)

