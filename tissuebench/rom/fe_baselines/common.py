"""What the three practitioner baselines share: the scene, the loads, the map to the fine mesh, outputs.

Each baseline solves a full finite-element problem (the scene's mesh or a coarser one) and
hands back the field on the scene's own mesh, so it is measured against the reference like
any ROM. The pieces:

* :func:`scene_of`: the scene of a training (``Training.scene``, else loaded by name and
  checked against ``info["scene_hash"]``), None when the training names none;
* :func:`intact_backend`: the backend of the scene without its ``[cut]`` (a baseline is not a
  cutting model; on cornea_cut it is the intact organ the PGD vademecums also start from);
* :class:`DeadLoads`: a backend whose loads are replaced by one dead force vector ``lam f``
  (a load transferred to a coarser mesh, a contact moved onto another node);
* :class:`FieldMap`: from the solving problem's dofs to the fine field (identity, or
  barycentric interpolation from a coarser mesh), the fine prescribed values placed exactly,
  and the output functionals of the fine mesh pulled back to the solving dofs;
* :class:`FeModel`: the online model base (state ``q`` = the solving problem's free dofs).

Units are the scene's; shapes are stated per function.
"""
from __future__ import annotations

import dataclasses

import numpy as np
import scipy.sparse as sp

from ..base import OnlineModel, StepResult, Training
from ..training_scene import scene_of

__all__ = ["scene_of", "intact_backend", "DeadLoads", "FieldMap", "FeModel", "contact_load",
           "contact_nodes_of"]


def intact_backend(training: Training, scene, who: str):
    """The training's backend, or one of the scene without its ``[cut]`` (same backend type)."""
    be = training.backend
    if be is None:
        raise ValueError(f"{who}: needs a finite-element training (training.backend is None)")
    if scene is None or getattr(scene, "cut", None) is None:
        return be
    from ..pgd.training import uncut_backend

    return uncut_backend(training, scene, who)


class DeadLoads:
    """A backend with its loads replaced by the dead force ``load_factor * force`` (shape (ndof,)).

    Everything else (internal forces, tangents, mass, Dirichlet data) is the wrapped
    backend's; Newton, the integrators and :meth:`SecondOrderSystem.from_backend` take it
    as a backend (they use the interface only)."""

    def __init__(self, backend, force):
        self._backend, self.force = backend, np.asarray(force, dtype=float)
        if self.force.shape != (backend.ndof,):
            raise ValueError(f"DeadLoads: force has shape {self.force.shape}, expected ({backend.ndof},)")

    def __getattr__(self, name):
        return getattr(self._backend, name)

    def external_force(self, u, load_factor):
        return float(load_factor) * self.force

    def external_tangent(self, u, load_factor):
        return None


def contact_load(problem, node: int) -> np.ndarray:
    """The force vector (ndof,) of the problem's single point load moved onto mesh ``node``."""
    from ..pgd.training import contact_force

    n = problem.mesh.n_vertices
    if isinstance(node, bool) or not float(node).is_integer() or not 0 <= int(node) < n:
        raise ValueError(f"contact node = {node!r}: not a node of the mesh (0 .. {n - 1})")
    f = np.zeros(problem.ndof)
    f[3 * int(node):3 * int(node) + 3] = contact_force(problem)
    return f


def contact_nodes_of(scene, problem):
    """The accessible contact nodes of a layered cornea dome (the anterior surface's free nodes, as
    the PGD vademecums take them: the ``contact_nodes`` evaluation picks from this list), else None."""
    from ..pgd.family import anterior_nodes

    if scene is None:
        return None
    intact = scene if scene.cut is None else dataclasses.replace(scene, cut=None)
    try:
        return anterior_nodes(problem.mesh, intact.mesh_info, problem.free_dofs)
    except ValueError:
        return None


class FieldMap:
    """From the solving problem's dofs to the fine field (module docstring).

    Parameters
    ----------
    solve_problem : Problem
        The problem the baseline solves (the scene's, or a coarser mesh's).
    fine_problem : Problem, optional
        The scene's problem the reference lives on (default: ``solve_problem``).
    nodal_map : (n_fine_nodes, n_solve_nodes) sparse, optional
        Interpolation weights of the solving nodes at the fine nodes (rows sum to 1);
        required when the problems differ.
    """

    def __init__(self, solve_problem, fine_problem=None, nodal_map=None):
        self.solve, self.fine = solve_problem, fine_problem or solve_problem
        self.same = fine_problem is None or fine_problem is solve_problem
        if not self.same and nodal_map is None:
            raise ValueError("FieldMap: a coarser solving problem needs its nodal_map")
        self.T = None if self.same else sp.kron(sp.csr_matrix(nodal_map), sp.identity(3), format="csr")
        if self.T is not None and self.T.shape != (self.fine.ndof, self.solve.ndof):
            raise ValueError(f"FieldMap: nodal_map gives {self.T.shape}, expected "
                             f"({self.fine.ndof}, {self.solve.ndof}) dofs")
        self.free, self.fixed = np.asarray(solve_problem.free_dofs), np.asarray(solve_problem.fixed_dofs)
        self.fine_fixed = np.asarray(self.fine.fixed_dofs)

    @property
    def ndof(self) -> int:
        return self.fine.ndof

    def solve_field(self, q, fixed_values) -> np.ndarray:
        u = np.zeros(self.solve.ndof)
        u[self.free] = q
        if len(self.fixed):
            u[self.fixed] = fixed_values
        return u

    def fine_field(self, u_solve, load_factor) -> np.ndarray:
        """The fine field (n_fine_dof,): interpolated, the fine prescribed values placed exactly."""
        if self.same:
            return u_solve
        u = self.T @ u_solve
        if len(self.fine_fixed):
            u[self.fine_fixed] = self.fine.prescribed_values(load_factor)
        return u

    def to_solve(self, f_fine) -> np.ndarray:
        """A dead nodal force of the fine mesh on the solving dofs: ``T^T f`` (consistent transfer)."""
        return f_fine if self.same else self.T.T @ f_fine

    def output_operators(self, operators: dict):
        """``(names, D_free, D_fixed, C_fine_fixed, skipped)`` with ``y = D_free q + D_fixed u_fixed +
        C_fine_fixed g_fine(lam)`` for the functionals ``{name: c (n_fine_dof,)}`` of the fine mesh;
        functionals of another size (a cut mesh's) are skipped and named."""
        names = [n for n, c in operators.items() if np.shape(c) == (self.ndof,)]
        skipped = [n for n in operators if n not in names]
        if not names:
            return (), None, None, None, skipped
        C = sp.csr_matrix(np.array([operators[n] for n in names], dtype=float))
        C_ff = C[:, self.fine_fixed] if len(self.fine_fixed) and not self.same else None
        if not self.same:
            keep = np.ones(self.ndof)
            keep[self.fine_fixed] = 0.0
            C = sp.csr_matrix(C @ sp.diags(keep) @ self.T)
        return names, C[:, self.free], C[:, self.fixed] if len(self.fixed) else None, C_ff, skipped


class FeModel(OnlineModel):
    """Online base of the baselines: ``q`` = the solving problem's free displacements (n_free,).

    ``result.info["fixed"]`` may carry the solving problem's fixed-dof values (a trajectory's
    prescribed motion); else they are the prescribed values at ``mu["load_factor"]``."""

    kind = "map"
    #: the accessible contact nodes (:func:`contact_nodes_of`) when the build found a single point
    #: load to move over them, else None: what :meth:`contact_nodes` answers
    accessible_nodes: np.ndarray | None = None

    def __init__(self, name: str, fmap: FieldMap, info: dict):
        self.name, self.fmap, self.info = name, fmap, dict(info)
        self.ndof = fmap.ndof

    def contact_nodes(self) -> np.ndarray | None:
        return self.accessible_nodes

    def step_parameters(self) -> tuple:
        """``node`` where the build found a single point load to move (the step moves it there)."""
        return (("node",) if getattr(self, "_contact", None) is not None else ()) + super().step_parameters()

    @property
    def n_reduced(self) -> int:
        return len(self.fmap.free)

    def _lam(self, result) -> float:
        if result.mu is None or "load_factor" not in result.mu:
            raise ValueError(f"{self.name}.reconstruct: the result carries no load factor (mu), so the prescribed "
                             "displacements cannot be placed")
        return float(result.mu["load_factor"])

    def _fixed_values(self, result, lam):
        fixed = result.info.get("fixed")
        return self.fmap.solve.prescribed_values(lam) if fixed is None else fixed

    def reconstruct(self, result: StepResult) -> np.ndarray:
        if result.q is None:
            raise ValueError(f"{self.name}.reconstruct: the step failed ({result.message}); no state")
        lam = self._lam(result)
        return self.fmap.fine_field(self.fmap.solve_field(result.q, self._fixed_values(result, lam)), lam)

    def attach_outputs(self, operators) -> None:
        names, D_free, D_fixed, C_ff, skipped = self.fmap.output_operators(dict(operators))
        self._outputs = (names, D_free, D_fixed, C_ff)
        if skipped:
            self.info["outputs_skipped"] = skipped

    def outputs(self, result: StepResult) -> dict:
        names, D_free, D_fixed, C_ff = getattr(self, "_outputs", ((), None, None, None))
        if not names:
            return {}
        if result.q is None:
            return {n: float("nan") for n in names}
        y = D_free @ result.q
        if D_fixed is not None or C_ff is not None:
            lam = self._lam(result)
            if D_fixed is not None:
                y = y + D_fixed @ self._fixed_values(result, lam)
            if C_ff is not None:
                y = y + C_ff @ self.fmap.fine.prescribed_values(lam)
        return dict(zip(names, np.asarray(y, float).tolist()))


def replace_material(problem, material):
    """``problem`` with another material (same mesh, element, Dirichlet data, loads)."""
    return dataclasses.replace(problem, material=material)
