"""Structured output of a time integration and the per-step energy bookkeeping.

Energy balance (all in J, free dofs only)::

    KE_n + IE_n + D_n - W_n - (KE_0 + IE_0) = energy_error_n

with KE = 1/2 v.M v, IE the stored (strain) energy, W the external work and D the
damping dissipation, both accumulated by the trapezoidal rule over each step
(W += 1/2 (f_n + f_{n+1}).(u_{n+1} - u_n), D likewise with C v). For the trapezoidal
rule on a linear system with a load constant in time this balance is exact to
round-off; other schemes show their numerical dissipation (HHT, Bathe: negative
error) or growth (forward Euler: positive error) in it.

With a prescribed motion of the fixed dofs the balance runs over all dofs: KE uses the
full velocity, D the full ``C v``, and W also holds the work of the support forces
``R_c = [M a + C v + f_int]_c`` on the prescribed displacements (``reaction_work``,
trapezoidal rule as well). M and C are the scheme's own on all dofs (the lumped ones of
the explicit schemes), the ones its steps balance.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

STATUSES = ("success", "newton_failed", "blow_up", "energy_growth")


@dataclass
class DynamicsResult:
    """Per-step record of one integration (arrays truncated to the completed steps).

    Attributes
    ----------
    method : str
        Integrator name.
    dt : float
        Time step [s].
    t : (n_steps + 1,) array
        Times [s] of every completed step, ``t[0] = t0``.
    stored_steps : (n_stored,) int array
        Step indices whose states are stored in ``u``, ``v``, ``a``.
    dofs : (n_out,) int array
        Full-vector dof indices of the stored columns (all dofs by default).
    u, v, a : (n_stored, n_out) arrays
        Displacement [m], velocity [m/s], acceleration [m/s^2] at the stored steps.
    newton_iterations : (n_steps + 1,) int array
        Newton iterations (linear solves) per step; 0 at step 0 and for explicit schemes.
    converged : (n_steps + 1,) bool array
    kinetic_energy, strain_energy, external_work, damping_dissipation, energy_error :
        (n_steps + 1,) arrays [J], see the module docstring.
    wall_time : (n_steps + 1,) array
        Wall-clock seconds spent in each step (0 at step 0).
    status : str
        One of ``"success"``, ``"newton_failed"``, ``"blow_up"``, ``"energy_growth"``.
    message : str
        Human-readable account of the status.
    failed_step : int or None
        The step at which the run stopped, whichever way (kept for the readers of stored
        results): ``rejected_step`` or ``blow_up_step``, the one that is set; None on success.
    rejected_step : int or None
        The step that could not be computed (Newton failure, a non-finite state of an
        explicit step): it is not in the arrays, which end at step ``rejected_step - 1``.
    blow_up_step : int or None
        The step that was computed and recorded but whose energy exceeded ``blowup_factor``
        times the energy supplied: the arrays end with it (``n_steps == blow_up_step``).
    observations : list of dict
        What ``integrate(observe=...)`` returned at every completed step (empty without it).
    energy_growth_ratio : float
        ``max_n (KE + IE + D)_n / max_n (KE_0 + IE_0 + W_n)``: 1 for an exactly
        energy-consistent scheme, < 1 with numerical dissipation, > 1 with growth.
    reaction_work : (n_steps + 1,) array or None
        The part of ``external_work`` done by the support forces on a prescribed motion
        [J] (None without one).
    """

    method: str
    dt: float
    t: np.ndarray
    stored_steps: np.ndarray
    dofs: np.ndarray
    u: np.ndarray
    v: np.ndarray
    a: np.ndarray
    newton_iterations: np.ndarray
    converged: np.ndarray
    kinetic_energy: np.ndarray
    strain_energy: np.ndarray
    external_work: np.ndarray
    damping_dissipation: np.ndarray
    energy_error: np.ndarray
    wall_time: np.ndarray
    status: str = "success"
    message: str = ""
    failed_step: int | None = None
    energy_growth_ratio: float = 1.0
    options: dict = field(default_factory=dict)
    observations: list = field(default_factory=list)
    reaction_work: np.ndarray | None = None
    rejected_step: int | None = None
    blow_up_step: int | None = None

    @property
    def success(self) -> bool:
        return self.status == "success"

    @property
    def n_steps(self) -> int:
        """Number of completed steps."""
        return len(self.t) - 1

    @property
    def t_stored(self) -> np.ndarray:
        return self.t[self.stored_steps]

    @property
    def total_energy(self) -> np.ndarray:
        """KE + IE [J] per step."""
        return self.kinetic_energy + self.strain_energy

    @property
    def relative_energy_error(self) -> np.ndarray:
        """energy_error divided by the largest energy or work seen in the run."""
        scale = max(np.max(np.abs(self.total_energy)), np.max(np.abs(self.external_work)), 1e-300)
        return self.energy_error / scale


class Recorder:
    """Accumulates states and energies step by step for a :class:`DynamicsResult`.

    Parameters
    ----------
    system : SecondOrderSystem
    mass_ff : sparse (n_free, n_free)
        The mass the integrator really uses (lumped for central difference), so the
        kinetic energy is the scheme's own.
    n_steps : int
        Steps planned (arrays are preallocated, then truncated).
    dofs : int array, optional
        Full-vector dofs to store (default all).
    store_every : int
        Store the state every this many steps (and always the last one).
    damping_force : callable ``v -> (n_free,)``, optional
        The scheme's C v [N] (default the system's).
    mass_full : sparse (n, n), optional
        The scheme's mass on all dofs (kinetic energy with a prescribed motion; default M).
    damping_full : sparse (n, n), optional
        The scheme's damping on all dofs (dissipation and support forces with a prescribed
        motion; default the system's ``C_full``).
    """

    def __init__(self, system, mass_ff, n_steps, dofs=None, store_every=1, damping_force=None, mass_full=None,
                 damping_full=None):
        self.system, self.M = system, mass_ff
        self.prescribed = system.has_prescribed
        self.M_full = system.M if mass_full is None else mass_full
        self.C_full = system.C_full if damping_full is None else damping_full
        self.damping_force = system.damping_force if damping_force is None else damping_force
        n = system.n
        self.dofs = np.arange(n) if dofs is None else np.asarray(dofs, dtype=np.int64).ravel()
        if self.dofs.size and (self.dofs.min() < 0 or self.dofs.max() >= n):
            raise ValueError(f"dofs: index out of range 0..{n - 1}")
        if int(store_every) != store_every or store_every < 1:
            raise ValueError(f"store_every must be an integer >= 1, got {store_every!r}")
        self.store_every = int(store_every)
        size = n_steps + 1
        self.t = np.zeros(size)
        self.iters = np.zeros(size, dtype=np.int64)
        self.conv = np.ones(size, dtype=bool)
        self.ke, self.ie, self.w, self.d, self.wall, self.rw = (np.zeros(size) for _ in range(6))
        self.states, self.steps = [], []
        self.k = -1
        self._prev = None  # (u, v, f_ext, f_int, fixed dofs' state) of the last recorded step

    def _full_cols(self, x_f, x_c=None):
        return self.system.expand(x_f, x_c)[self.dofs]

    def record(self, t, u, v, a, f_ext, f_int=None, iterations=0, converged=True, wall=0.0,
               force_store=False, constrained=None):
        """Record step ``k + 1``: free-dof state (u, v, a), external and internal force [N];
        ``constrained = (uc, vc, ac)`` is the state of the fixed dofs (prescribed motion).

        ``f_int`` is only used (and recomputed when None) if the system has no
        strain-energy function; with a prescribed motion the force on all dofs is recomputed.
        """
        self.k += 1
        k = self.k
        sys = self.system
        self.t[k], self.iters[k], self.conv[k], self.wall[k] = t, iterations, converged, wall
        uc, vc, ac = constrained if (self.prescribed and constrained is not None) else (None, None, None)
        if uc is None:
            self.ke[k] = 0.5 * float(v @ (self.M @ v))
        else:
            v_full = sys.expand(v, vc)
            self.ke[k] = 0.5 * float(v_full @ (self.M_full @ v_full))
            support = sys.support_force(u, uc, v_full, sys.expand(a, ac), self.M_full, self.C_full)
        energy = sys.energy(u, uc)
        if energy is None:
            # the internal work is accumulated instead; with a prescribed motion the fixed dofs move
            # too, so it takes the force on all dofs (f_int_c . du_c is work the support does)
            if uc is not None:
                f_int = np.asarray(sys.internal_force(sys.expand(u, uc)), dtype=float)
            elif f_int is None:
                f_int = sys.f_int(u, uc)
        if self._prev is None:
            self.ie[k] = 0.0 if energy is None else energy
        else:
            u0, v0, f0, fi0, c0 = self._prev
            du = u - u0
            self.w[k] = self.w[k - 1] + 0.5 * float((f0 + f_ext) @ du)
            if uc is None:
                cv = self.damping_force(v0) + self.damping_force(v)
                self.d[k] = self.d[k - 1] + 0.5 * float(cv @ du)
            else:
                uc0, vc0, support0 = c0
                self.rw[k] = self.rw[k - 1] + 0.5 * float((support0 + support) @ (uc - uc0))
                self.w[k] += self.rw[k] - self.rw[k - 1]
                if self.C_full is not None:
                    du_full = sys.expand(du, uc - uc0)
                    cv = self.C_full @ (sys.expand(v0, vc0) + sys.expand(v, vc))
                    self.d[k] = self.d[k - 1] + 0.5 * float(cv @ du_full)
            if energy is None:  # the internal work by the trapezoidal rule, on all dofs that move
                du_int = du if uc is None else sys.expand(du, uc - c0[0])
                self.ie[k] = self.ie[k - 1] + 0.5 * float((fi0 + f_int) @ du_int)
            else:
                self.ie[k] = energy
        c = None if uc is None else (uc.copy(), vc.copy(), support)
        self._prev = (u.copy(), v.copy(), np.array(f_ext, dtype=float), f_int, c)
        if force_store or k % self.store_every == 0:
            self.store(k, u, v, a, constrained)

    def store(self, k, u, v, a, constrained=None):
        if self.steps and self.steps[-1] == k:
            return
        uc, vc, ac = constrained if constrained is not None else (None, None, None)
        self.steps.append(k)
        self.states.append((self._full_cols(u, uc), self._full_cols(v, vc), self._full_cols(a, ac)))

    def mechanical(self):
        """(KE + IE + D) and (KE_0 + IE_0 + W) up to the current step."""
        k = self.k + 1
        return (self.ke[:k] + self.ie[:k] + self.d[:k],
                self.ke[0] + self.ie[0] + self.w[:k])

    def growth_ratio(self) -> float:
        mech, supplied = self.mechanical()
        top = np.max(mech)
        ref = np.max(supplied)
        if ref <= 0:
            return 1.0 if top <= 0 else np.inf
        return float(top / ref)

    def finish(self, method, dt, status, message, failed_step, options, blown_up=False) -> DynamicsResult:
        """The result; ``failed_step`` is the step that was rejected (not recorded), or with
        ``blown_up=True`` the recorded step whose energy blew up."""
        k = self.k + 1
        mech, supplied = self.mechanical()
        u, v, a = (np.array([s[i] for s in self.states]).reshape(len(self.states), len(self.dofs))
                   for i in range(3))
        return DynamicsResult(
            method=method, dt=dt, t=self.t[:k].copy(), stored_steps=np.array(self.steps, dtype=np.int64),
            dofs=self.dofs, u=u, v=v, a=a, newton_iterations=self.iters[:k].copy(),
            converged=self.conv[:k].copy(), kinetic_energy=self.ke[:k].copy(),
            strain_energy=self.ie[:k].copy(), external_work=self.w[:k].copy(),
            damping_dissipation=self.d[:k].copy(), energy_error=mech - supplied,
            wall_time=self.wall[:k].copy(), status=status, message=message, failed_step=failed_step,
            energy_growth_ratio=self.growth_ratio(), options=dict(options),
            reaction_work=self.rw[:k].copy() if self.prescribed else None,
            rejected_step=None if blown_up else failed_step, blow_up_step=failed_step if blown_up else None)
