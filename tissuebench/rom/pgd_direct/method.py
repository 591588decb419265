"""``"pgd_direct"``: the PGD-POD direct time integrator (pgd-pod-direct-integration).

Offline (:meth:`DirectIntegrator.build`): POD bases of the state fields from the training
trajectories, an interval per reduced coordinate and for the load factor (training range
plus ``margin``), a uniform mesh of ``n_nodes`` per parameter, and the PGD vademecum of
one step of the inner ``integrator`` (:mod:`.offline`). Online (:class:`DirectModel`):
each step evaluates the vademecum at the previous reduced state and the step's load
factor and projects the result back on the bases — O(P x N) work, no full-size vector.
"""
from __future__ import annotations

import time

import numpy as np

from ..base import POLYNOMIAL_MATERIALS, Applies, RomMethod, Training, register
from .balance import rotate_fields
from .meshes import ParameterMesh, parameter_domain
from .model import DirectModel
from .nonlinear import svk_internal_force_field
from .offline import PgdSettings, build_vademecum
from .operators import load_factors, state_bases, step_operators
from ..polynomial import check_polynomial_problem
from .schemes import SCHEMES

__all__ = ["DirectIntegrator"]


def _positive_int(name, value, minimum=1):
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise ValueError(f"pgd_direct: {name} must be an integer >= {minimum}, got {value!r}")
    return int(value)


def basis_floor_rmse(training, basis) -> float:
    """Relative RMSE of the training displacements' best (Euclidean) approximation in the span
    of the displacement ``basis`` (n_free, k): a floor for any trajectory in that span. When the
    evaluation replays the training trajectory (the presets), no vademecum, parameter mesh or
    inner scheme can do better than this with these POD modes."""
    U = np.asarray(training.snapshots)[np.asarray(training.free_dofs)]
    Q, _ = np.linalg.qr(basis)
    den = float(np.sum(U ** 2))
    return float(np.sqrt(np.sum((U - Q @ (Q.T @ U)) ** 2) / den)) if den > 0 else float("nan")


def _nonlinear(scene) -> bool:
    """The scene's semi-discrete system is nonlinear (a finite-strain material, a follower load)."""
    return scene.is_fe and (scene.material["name"] != "linear" or any(ld["type"] == "follower_pressure"
                                                                      for ld in scene.loads))


@register
class DirectIntegrator(RomMethod):
    """PGD-POD direct time integrator.

    Parameters
    ----------
    pod_modes : int
        POD modes per state field (the reduced coordinates of the initial conditions).
    integrator : {"forward_euler", "central_difference", "bathe", "hht"}
        Scheme inside the step (:mod:`.schemes`); the paper's "forward Euler" on
        ``u^n, u^{n-1}`` is ``central_difference`` here.
    pgd_modes : int, optional
        Largest number of modes of every PGD solve of the step (None: 200; the amplitude
        criterion ``pgd_tol`` usually stops first).
    n_nodes : int
        Nodes of each parameter mesh (paper Remark 2: 100).
    margin : float
        Widening of every parameter interval beyond the training values (see
        :func:`~.meshes.parameter_domain`).
    symmetric : bool
        Intervals centred on zero (default; see :func:`~.meshes.parameter_domain`).
    velocity_basis : {"velocity", "displacement"}
        Basis of the velocity fields: their own POD ("velocity", default) or the
        displacement basis (as in a Galerkin ROM, where v lies in the span of the
        displacement modes; fewer distinct spaces, the velocity coordinates' intervals
        still come from the training velocities).
    balance : {"field", "none"}
        Coordinates in which the PGD sees the previous state (:mod:`.balance`): each POD
        basis rotated in its space so that the step map's columns are orthogonal
        ("field", default), or the POD modes themselves ("none").
    dt : float, optional
        Time step [s] (default: the training's).
    alpha : float
        HHT parameter in [-1/3, 0].
    load_at : {"end", "start", "mid"}
        Load factor held over a step: the one passed to that step (``"end"``), the
        previous step's (``"start"``, the paper's value at the beginning of the step) or
        their mean (``"mid"``: second order in dt for a smooth load history).
    mass : {"consistent", "lumped"}
    pgd_tol, max_fixed_point, fixed_point_tol, seed
        PGD settings (:class:`~.offline.PgdSettings`).
    """

    name = "pgd_direct"
    kind = "trajectory"
    nested = ()
    training_kinds = ("trajectory",)
    applies = Applies(models=("fe", "poisson1d", "frame2dof", "hermite_beam"), dead_loads=True)

    @classmethod
    def why_not(cls, scene, options=None) -> str:
        """Besides the declaration: a nonlinear system needs the SVK tensors (a polynomial
        material) and then an explicit scheme inside the step (§6.2)."""
        why = super().why_not(scene, options)
        if why or not _nonlinear(scene):
            return why
        material = scene.material["name"]
        if material not in POLYNOMIAL_MATERIALS:
            return (f"material {material!r} is not polynomial in the displacement; the nonlinear direct integrator "
                    "needs Saint Venant-Kirchhoff (or linear) elasticity (the SVK internal force in separated form)")
        integrator = (options or {}).get("integrator", "forward_euler")
        if SCHEMES[integrator].implicit:
            return (f"integrator {integrator!r} is implicit and the system is nonlinear; use forward_euler or "
                    "central_difference (explicit treatment, §6.2)")
        return ""

    @classmethod
    def note(cls, scene) -> str:
        return "explicit integrators only (forward_euler, central_difference): nonlinear SVK system" \
            if scene.is_fe and _nonlinear(scene) else ""

    def __init__(self, pod_modes: int = 8, integrator: str = "forward_euler", pgd_modes: int | None = None,
                 n_nodes: int = 100, margin: float = 0.25, symmetric: bool = True, balance: str = "field",
                 velocity_basis: str = "velocity",
                 dt: float | None = None, alpha: float = -0.05, load_at: str = "end", mass: str = "consistent",
                 pgd_tol: float = 1e-8, max_fixed_point: int = 100, fixed_point_tol: float = 1e-12, seed: int = 0):
        if integrator not in SCHEMES:
            raise ValueError(f"pgd_direct: integrator = {integrator!r}; valid: {sorted(SCHEMES)}")
        if load_at not in ("end", "start", "mid"):
            raise ValueError(f"pgd_direct: load_at = {load_at!r}; valid: ['end', 'start', 'mid']")
        if mass not in ("consistent", "lumped"):
            raise ValueError(f"pgd_direct: mass = {mass!r}; valid: ['consistent', 'lumped']")
        if not (np.isfinite(alpha) and -1.0 / 3.0 <= alpha <= 0.0):
            raise ValueError(f"pgd_direct: alpha must lie in [-1/3, 0], got {alpha!r}")
        if not (np.isfinite(margin) and margin >= 0.0):
            raise ValueError(f"pgd_direct: margin must be finite and >= 0, got {margin!r}")
        if dt is not None and not (np.isfinite(dt) and dt > 0):
            raise ValueError(f"pgd_direct: dt must be a finite time step > 0, got {dt!r}")
        for name, v in (("pgd_tol", pgd_tol), ("fixed_point_tol", fixed_point_tol)):
            if not (np.isfinite(v) and v >= 0):
                raise ValueError(f"pgd_direct: {name} must be finite and >= 0, got {v!r}")
        self.pod_modes = _positive_int("pod_modes", pod_modes)
        self.pgd_modes = None if pgd_modes is None else _positive_int("pgd_modes", pgd_modes)
        self.n_nodes = _positive_int("n_nodes", n_nodes, 2)
        self.max_fixed_point = _positive_int("max_fixed_point", max_fixed_point)
        self.integrator, self.margin, self.symmetric, self.dt = integrator, float(margin), bool(symmetric), dt
        if balance not in ("field", "none"):
            raise ValueError(f"pgd_direct: balance = {balance!r}; valid: ['field', 'none']")
        self.balance = balance
        if velocity_basis not in ("velocity", "displacement"):
            raise ValueError(f"pgd_direct: velocity_basis = {velocity_basis!r}; valid: ['velocity', 'displacement']")
        self.velocity_basis = velocity_basis
        self.alpha, self.load_at, self.mass = float(alpha), load_at, mass
        self.pgd_tol, self.fixed_point_tol, self.seed = float(pgd_tol), float(fixed_point_tol), int(seed)

    def _meshes(self, coords: dict, lams):
        """One mesh per coordinate (field by field), then the load factor's.

        A coordinate's interval is ``(1 + margin)`` times its largest training value, but at
        least ``margin`` times the largest training norm of its field's coordinates: a
        direction hardly excited in training (a small singular value) must not flag every
        small deviation of the reduced trajectory as an extrapolation.
        """
        meshes = []
        for Q in coords.values():
            floor = self.margin * float(np.max(np.linalg.norm(Q, axis=0)))
            for c in Q:
                meshes.append(ParameterMesh(*parameter_domain(c, self.margin, self.symmetric, floor), self.n_nodes))
        meshes.append(ParameterMesh(*parameter_domain(lams, self.margin, self.symmetric), self.n_nodes))
        return meshes

    def _operators(self, training: Training):
        """(scheme, dt, StepOperators) with the checks that need the training."""
        scheme = SCHEMES[self.integrator]
        dt = self.dt if self.dt is not None else training.dt
        if dt is None:
            raise ValueError("pgd_direct: no time step (give dt or a training with dt)")
        ops = step_operators(training, self.mass)
        if not ops.linear and training.backend is not None:
            # the material first: no integrator helps a non-polynomial one (the advice below would
            # lead to a second refusal)
            check_polynomial_problem(training.backend.problem, "pgd_direct")
        if scheme.implicit and not ops.linear:
            raise ValueError(f"pgd_direct: integrator {self.integrator!r} is implicit and the system is "
                             "nonlinear; use forward_euler or central_difference (explicit treatment, §6.2)")
        return scheme, dt, ops

    def _bases(self, training, ops, scheme, dt):
        """(bases per state field, training coordinates per state field, StateBases, balance record)."""
        fields = scheme.state_fields(ops.C is not None)
        basis_of = {f: "u" if self.velocity_basis == "displacement" else scheme.basis[f] for f in fields}
        sb = state_bases(training, ops, list(dict.fromkeys(basis_of.values())), self.pod_modes,
                         need_velocities=any(scheme.basis[f] == "v" for f in fields))
        free = np.asarray(training.free_dofs)
        data = {"u": training.snapshots[free],
                "v": None if training.velocities is None else training.velocities[free]}
        # each output field weighs by its training RMS (M-norm) in the balancing Gram matrix
        rms = {k: float(np.sqrt(np.mean(np.einsum("is,is->s", X, ops.M @ X)))) for k, X in data.items()
               if X is not None}
        scales = {f: 1.0 / rms[scheme.basis[f]] if rms[scheme.basis[f]] > 0 else 1.0 for f in scheme.outputs}
        balance = {}
        if self.balance == "field":
            cov = {}
            for kind in dict.fromkeys(scheme.basis[f] for f in fields):  # u, v data in the bases they use
                b = {scheme.basis[f]: basis_of[f] for f in fields}[kind]
                Q = sb.bases[b].T @ (ops.M @ data[kind])
                cov[b] = cov.get(b, 0.0) + (Q @ Q.T) / max(np.trace(Q @ Q.T), 1e-300)
            balance = rotate_fields(sb, ops, scheme, dt, scales, basis_of, cov, alpha=self.alpha)
        bases = {f: sb.bases[basis_of[f]] for f in fields}
        # a field's coordinates: its own snapshots (u_prev: displacements) projected on its basis
        coords = {f: bases[f].T @ (ops.M @ data[scheme.basis[f]]) for f in fields}
        return bases, coords, sb, balance

    def build(self, training: Training) -> DirectModel:
        """Offline phase (see the module docstring); ValueError on an unusable training."""
        t0 = time.perf_counter()
        scheme, dt, ops = self._operators(training)
        bases, coords, sb, balance = self._bases(training, ops, scheme, dt)
        meshes = self._meshes(coords, load_factors(training))
        fint, n_evals = None, 0
        if not ops.linear:
            if training.backend is None:
                raise ValueError("pgd_direct: a nonlinear system needs training.backend (SVK polynomial force)")
            fint, n_evals = svk_internal_force_field(training.backend, bases["u"], list(range(bases["u"].shape[1])),
                                                     meshes, np.asarray(training.free_dofs))
        settings = PgdSettings(max_modes=self.pgd_modes or 200, tol=self.pgd_tol,
                               max_fixed_point=self.max_fixed_point, fixed_point_tol=self.fixed_point_tol,
                               seed=self.seed)
        vad = build_vademecum(ops, scheme, bases, meshes, dt, settings, fint, alpha=self.alpha)
        vad.stats.update({"pod_energy": sb.energy, "basis_floor_rmse": basis_floor_rmse(training, bases["u"]),
                          "svk_force_evaluations": n_evals, "balance": self.balance,
                          "build_s": time.perf_counter() - t0, "pod_modes": {k: b.shape[1] for k, b in bases.items()},
                          "balance_singular_values": {k: v.tolist() for k, v in balance.items()}})
        model = DirectModel(vad, ops, bases, np.asarray(training.free_dofs), training.snapshots.shape[0],
                            self.load_at)
        if training.outputs:
            model.attach_outputs(training.outputs)
        return model
