"""``"corotational_fe"``: corotational linear FEM on the scene's mesh (SOFA's ``TetrahedronFEMForceField``
method "polar", Vega FEM's corotational linear material).

Per element, the rotation ``R`` of the polar decomposition of F (by SVD) and the linear
stiffness in the rotated frame, ``f_e = R K_e (R^T x_e - X_e)``: the material
:class:`~tissuebench.refsolvers.corotational.Corotational` with the scene material's
small-strain moduli, consumed through the scikit-fem backend's interface (NGSolve's backend
needs a symbolic energy, which the polar decomposition has not: the reason is in
:mod:`tissuebench.refsolvers.corotational`; the operators are built on scikit-fem whatever
the case's backend, on the same mesh and dof numbering, so the field compares as is).

* Statics (``kind = "path"``): Newton with the consistent tangent, continued from the last
  converged state and its load factor to the step's, kept on the descent of the potential
  energy (:class:`~.continuation.ContinuationPathModel`); the scene's dead loads and Dirichlet
  data. A follower pressure is kept as the scene's own. The material is defined through
  inversion (:mod:`tissuebench.refsolvers.corotational`): under a point load its equilibrium
  inverts the cells under the load and snaps through as they go, and the step follows it.
* Dynamics (``kind = "trajectory"``): the scene's integrator (or ``integrator``; SOFA's
  default is backward Euler) with Newton iterations per step on the corotational forces.

Options: ``rtol``, ``max_iterations``, ``min_increment`` (the Newton of a static step,
:mod:`~.continuation`: a step goes from the last converged load factor to its own, an
increment that fails is halved down to ``min_increment`` of the step; a step spends at most
``max_iterations x (1 + log2(1 / min_increment))`` Newton iterations, 75 by default, and is
then a failed step: past where the model has an equilibrium, a sweep or a dense check carries
on at that cost), ``linear_solver`` ("auto": NGSolve's sparse Cholesky from 1000 unknowns,
SuperLU below; "amg-cg"), ``integrator``.
"""
from __future__ import annotations

import numpy as np

from ...reference.formulation import formulation_of
from ...refsolvers.backends import make_backend
from ...refsolvers.corotational import Corotational, small_strain_moduli
from ..base import Applies, RomMethod, Training, register
from .common import FieldMap, contact_nodes_of, intact_backend, replace_material, scene_of
from .continuation import ContinuationPathModel
from .linear import _contact_of, is_dynamic
from .stepping import (TrajectoryModel, dynamic_system, integrator_choice, load_history,
                       newton_options, with_atol)

__all__ = ["CorotationalFe", "corotational_backend", "roundoff_force"]


def corotational_backend(backend):
    """A scikit-fem backend of ``backend.problem`` with the corotational material of its small-strain moduli."""
    E, nu = small_strain_moduli(backend.problem.material)
    return make_backend("skfem", replace_material(backend.problem, Corotational(E, nu)))


def roundoff_force(backend, seed: int = 0) -> float:
    """The round-off floor [force] of the corotational internal force on the free dofs.

    ``P = 2 mu (F - R) + ...`` cancels to the size of the strain, so at small displacement the
    force carries an absolute error of about ``mu eps`` per unit area, far above a relative
    Newton tolerance of the load there (the liver's first time step, 0.02 N: ||r|| stalled at
    3.8e-12 N against 1.9e-12 N). Measured here as ``|f_int(u) - K(0) u|`` at a random ``u`` of
    1e-9 x the body's size (the quadratic term is ~1e-9 of the linear one there); Newton's
    absolute tolerance is ten times it."""
    pb = backend.problem
    free = pb.free_dofs
    u = np.zeros(pb.ndof)
    size = float(np.linalg.norm(np.ptp(pb.nodes, axis=0)))
    u[free] = 1e-9 * size * np.random.default_rng(seed).standard_normal(len(free))
    r = backend.internal_force(u) - backend.tangent(np.zeros(pb.ndof)) @ u
    return float(np.linalg.norm(r[free]))


@register
class CorotationalFe(RomMethod):
    """Corotational linear elasticity on the scene's mesh (module docstring)."""

    name = "corotational_fe"
    kind = "path"  # statics; on a dynamic scene the online model is a "trajectory"
    training_kinds = ("path", "operators", "trajectory")
    applies = Applies()  # any finite-element scene: it learns nothing, it solves the scene

    def __init__(self, rtol: float = 1e-9, max_iterations: int = 15, min_increment: float = 1.0 / 16,
                 linear_solver: str = "auto", integrator: str | None = None):
        newton_options(self.name, rtol, max_iterations, min_increment, linear_solver, 0)  # checks the values
        self.rtol, self.max_iterations, self.min_increment = rtol, max_iterations, min_increment
        self.linear_solver, self.integrator = linear_solver, integrator

    @classmethod
    def note(cls, scene) -> str:
        """Where the reference does not lock (average nodal pressure tetrahedra), corotated P1 does:
        what a practitioner's corotational tetrahedra give, stated before any work."""
        if getattr(scene, "is_fe", False) and formulation_of(scene).name == "anp":
            return ("corotated linear tetrahedra without nodal averaging: they lock where the reference (average "
                    "nodal pressure) does not, as a practitioner's corotational P1 would")
        return super().note(scene)

    def build(self, training: Training):
        scene = scene_of(training, self.name)
        be = corotational_backend(intact_backend(training, scene, self.name))
        E, nu = small_strain_moduli(be.problem.material)
        fmap = FieldMap(be.problem)
        info = {"physics": "corotational", "coarsening": 1.0, "n_dof": int(be.ndof), "E": E, "nu": nu,
                "backend": "skfem"}
        atol = 10.0 * roundoff_force(be)
        info["newton_atol"] = atol
        if is_dynamic(training, scene):
            name, options = integrator_choice(self.name, self.integrator, scene)
            history = load_history(training, scene)
            system = dynamic_system(be, training, name, False, history)
            return TrajectoryModel(self.name, system, (name, with_atol(name, options, atol)), fmap, info, history)
        opts = newton_options(self.name, self.rtol, self.max_iterations, self.min_increment, self.linear_solver,
                              len(fmap.free))
        opts["atol"] = atol
        info["linear_solver"] = opts["linear_solver"]
        contact = _contact_of(be.problem)
        model = ContinuationPathModel(self.name, be, fmap, info, opts, contact)
        model.info["step_budget"] = model.budget
        model.accessible_nodes = contact_nodes_of(scene, be.problem) if contact else None
        return model
