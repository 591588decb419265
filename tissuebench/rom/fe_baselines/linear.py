"""``"linear_fe"``: linear elasticity on the scene's mesh, factorised once (what a haptic trainer runs first).

The stiffness is the tangent of the scene's own backend at ``u = 0``: linear elasticity
with the material's small-strain moduli (for isotropic materials exactly that of
:func:`~tissuebench.refsolvers.corotational.small_strain_moduli`, tested; anisotropic ones
keep their fibres), dead loads at the reference configuration, the scene's Dirichlet data.
``K_ff`` is factorised offline (:func:`~tissuebench.refsolvers.sparse_direct.factorized`:
NGSolve's sparse Cholesky from 1000 unknowns, SuperLU below).

* Statics (``kind = "map"``): the haptic step is the back-substitution of
  ``K_ff u = lam f - K_fc u_D(lam)`` at the step's load factor (a haptic loop applies a new
  load every frame, so the solve is the step even where the load direction is fixed).
  ``mu["node"]`` moves the scene's single point load onto a mesh node (``contact_nodes``).
* ``condensed = True`` (Bro-Nielsen and Cotin 1996, "Real-time volumetric deformable models
  for surgery simulation using finite elements and condensation", Computer Graphics Forum
  15(3)): the inputs are the loaded dofs and the dofs whose prescribed displacement moves;
  offline ``G = K_ff^-1 [E_loaded, -K_f,moved]`` (n_free x n_inputs) and the compliance of the
  monitored outputs ``Y = C G`` (n_outputs x n_inputs); the haptic step forms the inputs and
  the outputs are one small dense product, the full field ``G z`` is the reconstruction.
  ``model_info`` says how many input dofs and outputs and the bytes of ``Y`` and ``G``.
* Dynamics (``kind = "trajectory"``): ``M a + K u = f(t)`` with the reference's mass kind,
  loads, prescribed motion and integrator (or ``integrator``), the effective matrix factorised
  once: one solve per step. On a scene whose material is linear this *is* the reference.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ...refsolvers.sparse_direct import factorized
from ..base import Applies, RomMethod, StepResult, Training, check_parameters, register
from .common import FeModel, FieldMap, contact_load, contact_nodes_of, intact_backend, scene_of
from .stepping import TrajectoryModel, dynamic_system, integrator_choice, load_history

__all__ = ["LinearFe", "LinearStaticModel", "CondensedLinearModel", "linear_static_model", "is_dynamic"]


def is_dynamic(training: Training, scene) -> bool:
    """A time-stepping case: a trajectory training, or a dynamic scene."""
    if training.dt is not None:
        return True
    return scene is not None and (scene.analysis or {}).get("type") == "dynamic"


def _moving_fixed(problem) -> np.ndarray:
    """Positions (in ``problem.fixed_dofs``) of the fixed dofs whose prescribed value is not zero
    (sampled at load factors 1, 1/2, 1/3: scaled values and rotations)."""
    if not len(problem.fixed_dofs):
        return np.zeros(0, dtype=np.int64)
    vals = np.array([problem.prescribed_values(lam) for lam in (1.0, 0.5, 1.0 / 3.0)])
    return np.flatnonzero(np.any(vals != 0.0, axis=0))


class LinearStaticModel(FeModel):
    """``K_ff u = lam f - K_fc u_D(lam)`` by back-substitution (module docstring)."""

    kind = "map"

    def __init__(self, name, backend, fmap, info, contact=None):
        super().__init__(name, fmap, info)
        u0 = np.zeros(backend.ndof)
        if backend.external_tangent(u0, 1.0) is not None:
            raise ValueError(f"{name}: follower loads are not linear elasticity (dead loads only)")
        pb = fmap.solve
        K = sp.csr_matrix(backend.tangent(u0))
        free, fixed = fmap.free, fmap.fixed
        self.K_ff = K[free][:, free]
        self._solve = factorized(self.K_ff)
        moving = _moving_fixed(pb)
        self._K_fm = K[free][:, fixed[moving]] if len(moving) else None
        self._moving = moving
        self.f1 = backend.external_force(u0, 1.0)[free]
        self._contact = contact
        self.info.update(n_free=int(len(free)), solver="ngsolve-cholesky" if len(free) >= 1000 else "superlu",
                         factor_of="K(0) on the free dofs")

    def _rhs(self, lam, node=None):
        f = self.f1 if node is None else self._contact(node)[self.fmap.free]
        rhs = lam * f
        if self._K_fm is not None:
            rhs = rhs - self._K_fm @ self.fmap.solve.prescribed_values(lam)[self._moving]
        return rhs

    def _mu(self, mu):
        mu = check_parameters(mu, ("load_factor",), self.name)
        out = {"load_factor": float(mu["load_factor"])}
        node = None
        if "node" in mu:
            if self._contact is None:
                raise ValueError(f"{self.name}.step: mu['node'] given but the scene has no single point load to move")
            node = out["node"] = int(mu["node"])
        return out, node

    def step(self, mu) -> StepResult:
        out, node = self._mu(mu)
        return StepResult(self._solve(self._rhs(out["load_factor"], node)), "ok", mu=out)

    def floor_ops(self):
        """The step's unavoidable arithmetic: one back-substitution with the offline factor."""
        b, solve = self.f1.copy(), self._solve
        return lambda: solve(b)


class CondensedLinearModel(LinearStaticModel):
    """Bro-Nielsen condensation: ``q`` = the inputs (loads on the loaded dofs, the moving
    prescribed values), outputs ``Y q``, field ``G q`` (module docstring)."""

    def __init__(self, name, backend, fmap, info, contact=None):
        super().__init__(name, fmap=fmap, backend=backend, info=info, contact=None)
        self._loaded = np.flatnonzero(self.f1)
        n_free = len(self.f1)
        E = sp.csr_matrix((np.ones(len(self._loaded)), (self._loaded, np.arange(len(self._loaded)))),
                          shape=(n_free, len(self._loaded)))
        cols = [E.toarray()]
        if self._K_fm is not None:
            cols.append(-self._K_fm.toarray())
        B = np.hstack(cols)
        if B.shape[1] == 0:
            raise ValueError(f"{name}: condensed = true needs loads or moving prescribed displacements (none found)")
        self.G = np.ascontiguousarray(np.asarray(self._solve(B)).reshape(n_free, B.shape[1]))
        self._f1_loaded = self.f1[self._loaded]
        self.info.update(condensed=True, loaded_dofs=int(len(self._loaded)), prescribed_dofs=int(len(self._moving)),
                         inputs=int(B.shape[1]), reconstruction_bytes=int(self.G.nbytes))

    @property
    def n_reduced(self) -> int:
        return self.G.shape[1]

    def _inputs(self, lam):
        z = lam * self._f1_loaded
        if self._K_fm is not None:
            z = np.concatenate([z, self.fmap.solve.prescribed_values(lam)[self._moving]])
        return z

    def step(self, mu) -> StepResult:
        out, node = self._mu(mu)
        return StepResult(self._inputs(out["load_factor"]), "ok", mu=out)

    def reconstruct(self, result) -> np.ndarray:
        if result.q is None:
            raise ValueError(f"{self.name}.reconstruct: the step failed ({result.message}); no state")
        lam = self._lam(result)
        return self.fmap.fine_field(self.fmap.solve_field(self.G @ result.q, self._fixed_values(result, lam)), lam)

    def attach_outputs(self, operators) -> None:
        super().attach_outputs(operators)
        names, D_free, D_fixed, C_ff = self._outputs
        if not names:
            self.info.update(outputs=0, compliance_bytes=0)
            return
        Y = np.asarray(D_free @ self.G)
        if D_fixed is not None and len(self._moving):
            Y[:, len(self._loaded):] += D_fixed[:, self._moving].toarray()
        self._Y, self._C_ff = np.ascontiguousarray(Y), C_ff
        self.info.update(outputs=len(names), compliance_bytes=int(Y.nbytes))

    def floor_ops(self):
        """The step's unavoidable arithmetic: the compliance product ``Y z`` (with no output, the
        inputs ``lam f``)."""
        from ..online import matvec_floor

        if getattr(self, "_Y", None) is not None:
            return matvec_floor(self._Y)
        f, z = self._f1_loaded, np.empty(len(self._f1_loaded))
        return lambda: np.multiply(f, 0.5, out=z)

    def outputs(self, result) -> dict:
        names = getattr(self, "_outputs", ((),))[0]
        if not names:
            return {}
        if result.q is None:
            return {n: float("nan") for n in names}
        y = self._Y @ result.q
        if self._C_ff is not None:
            y = y + self._C_ff @ self.fmap.fine.prescribed_values(self._lam(result))
        return dict(zip(names, y.tolist()))


def linear_static_model(name, backend, fmap, info, condensed=False, contact=None):
    cls = CondensedLinearModel if condensed else LinearStaticModel
    return cls(name, backend, fmap, info, contact)


@register
class LinearFe(RomMethod):
    """Linear elasticity on the scene's mesh, factorised once (module docstring).

    Parameters
    ----------
    condensed : bool
        Statics: precompute the compliance of the loaded/moved and monitored dofs (the step is a
        small dense product).
    integrator : str, optional
        Dynamics: the time integrator (default: the scene's, with its options).
    """

    name = "linear_fe"
    kind = "map"  # statics; on a dynamic scene the online model is a "trajectory"
    training_kinds = ("path", "operators", "trajectory")
    applies = Applies()  # any finite-element scene: it learns nothing, it solves the scene

    def __init__(self, condensed: bool = False, integrator: str | None = None):
        if not isinstance(condensed, bool):
            raise ValueError(f"linear_fe: condensed must be true or false, got {condensed!r}")
        self.condensed, self.integrator = condensed, integrator

    def build(self, training: Training):
        scene = scene_of(training, self.name)
        be = intact_backend(training, scene, self.name)
        fmap = FieldMap(be.problem)
        info = {"physics": "linear", "coarsening": 1.0, "n_dof": int(be.ndof)}
        if is_dynamic(training, scene):
            if self.condensed:
                raise ValueError("linear_fe: condensed = true is for statics (a dynamic step needs the mass)")
            integ = integrator_choice(self.name, self.integrator, scene)
            history = load_history(training, scene)
            system = dynamic_system(be, training, integ[0], True, history)
            return TrajectoryModel(self.name, system, integ, fmap, info, history)
        contact = _contact_of(be.problem)
        model = linear_static_model(self.name, be, fmap, info, self.condensed, contact)
        model.accessible_nodes = contact_nodes_of(scene, be.problem) if contact and not self.condensed else None
        return model


def _contact_of(problem):
    """``node -> force vector`` when the problem has one single-node point load, else None."""
    try:
        contact_load(problem, 0)
    except ValueError:
        return None
    return lambda node: contact_load(problem, node)
