"""``"pgd"``: the linear PGD vademecum of a moving point load, evaluated online by srb,
prb or the vademecum itself (pgd-vademecum-cutting §2).

Offline: the point-load family of the scene (:mod:`.training`: the stiffness K of the
space discretisation and the point loads in separated form, no snapshot), its PGD
vademecum (:func:`~.vademecum.build_vademecum`) and the reduced operators of the chosen
projection (:mod:`.projections`). Online, ``step({"position": s_p})`` (see
:mod:`.online` for the keys and the statuses) costs a few rows of the basis times the
force and an N x N product; ``reconstruct`` returns the full field.
"""
from __future__ import annotations

import numpy as np

from ..base import Applies, LinearReconstruction, OnlineModel, RomMethod, StepResult, Training, register
from .online import LocatedContact, locate
from .projections import make_projection
from .training import family_from_training
from .vademecum import Vademecum, build_vademecum

__all__ = ["Pgd", "PgdModel", "check_pgd_options"]

_PROJECTIONS = ("srb", "prb", "vademecum")


def check_pgd_options(who, n_modes, tol, max_fixed_point, fixed_point_tol, seed):
    """ValueError naming the first invalid vademecum option."""
    for name, v in (("n_modes", n_modes), ("max_fixed_point", max_fixed_point)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
            raise ValueError(f"{who}: {name} must be a positive integer, got {v!r}")
    for name, v in (("tol", tol), ("fixed_point_tol", fixed_point_tol)):
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not (np.isfinite(v) and v >= 0):
            raise ValueError(f"{who}: {name} must be a finite number >= 0, got {v!r}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)):
        raise ValueError(f"{who}: seed must be an integer, got {seed!r}")


@register
class Pgd(RomMethod):
    """PGD vademecum + online projection.

    Options
    -------
    n_modes : int, largest number of modes (the build may stop earlier, see ``tol``)
    projection : {"srb", "prb", "vademecum"}
    tol, max_fixed_point, fixed_point_tol, seed, update_last :
        of :func:`~tissuebench.rom.separated_solver.pgd_solve` (amplitude criterion relative to
        the first mode; sweeps and convergence of the alternating directions)
    s_nodes : int, optional, number of parameter nodes of a 1D scene (default: the
        scene's ``[methods.pgd] s_nodes_<resolution>``, else the mesh nodes)
    """

    name = "pgd"
    kind = "map"
    training_kinds = ("operators",)
    # a 1D point source, or a point load on the anterior surface of a layered shell (cornea_dome)
    applies = Applies(models=("fe", "poisson1d"), point_load=True, homogeneous_dirichlet=True,
                      mesh_builders=("cornea_dome",), parameters={"operators": ("position",)}, linear_model=True)

    @classmethod
    def reads(cls, scene, training_kind):
        """The position of the 1D source; on a surface, ``position`` is an index into the accessible
        nodes (``node`` a mesh node), not the scene's ``[parameters.position]`` coordinate."""
        return super().reads(scene, training_kind) if not scene.is_fe else ()

    def __init__(self, n_modes: int = 10, projection: str = "srb", tol: float = 1e-8, max_fixed_point: int = 50,
                 fixed_point_tol: float = 1e-8, seed: int = 0, update_last: bool = False, s_nodes=None):
        check_pgd_options(self.name, n_modes, tol, max_fixed_point, fixed_point_tol, seed)
        if projection not in _PROJECTIONS:
            raise ValueError(f"{self.name}: projection = {projection!r}; valid: {list(_PROJECTIONS)}")
        self.n_modes, self.projection, self.tol = int(n_modes), projection, float(tol)
        self.max_fixed_point, self.fixed_point_tol, self.seed = int(max_fixed_point), float(fixed_point_tol), int(seed)
        self.update_last, self.s_nodes = bool(update_last), s_nodes

    def vademecum(self, training: Training) -> Vademecum:
        """The offline vademecum alone (shared by the projections of a study)."""
        fam = family_from_training(training, self.name, self.s_nodes)
        return build_vademecum(fam, self.n_modes, self.tol, self.max_fixed_point, self.fixed_point_tol,
                               self.seed, self.update_last)

    def build(self, training: Training) -> OnlineModel:
        vad = self.vademecum(training)
        return PgdModel(self.name, vad, self.projection, getattr(training.backend, "problem", None))


class PgdModel(LocatedContact, LinearReconstruction, OnlineModel):
    """Online vademecum; ``q`` = coefficients on :attr:`basis` (srb: K-orthonormal basis
    of span X; prb and vademecum: the modes X)."""

    kind = "map"

    def __init__(self, name, vademecum: Vademecum, projection: str, problem=None):
        self.name, self.vademecum, self.projection = name, vademecum, projection
        self.proj = None if projection == "vademecum" else make_projection(projection, vademecum)
        self.basis = vademecum.X if self.proj is None else self.proj.basis
        fam = vademecum.family
        self.free_dofs, self.ndof, self.problem = fam.free_dofs, fam.ndof, problem

    @property
    def n_reduced(self) -> int:
        return self.basis.shape[1]

    def contact_nodes(self) -> np.ndarray | None:
        """The surface family's parameter nodes (None for a line family)."""
        return self.vademecum.family.nodes

    @property
    def envelope(self) -> dict:
        fam = self.vademecum.family
        if fam.kind == "line":
            return {"position": (float(fam.coords[0]), float(fam.coords[-1]))}
        return {"position": (0, fam.n_parameters - 1)}

    @property
    def info(self) -> dict:
        """Record of the offline build (the sweep's ``model_info``)."""
        return {**self.vademecum.build_info(), "projection": self.projection,
                "dropped_directions": getattr(self.proj, "n_dropped", 0)}

    def prescribed(self, mu):  # homogeneous Dirichlet conditions only (checked offline)
        fixed = np.setdiff1d(np.arange(self.ndof), self.free_dofs)
        return fixed, np.zeros(len(fixed))

    def prescribed_affine(self):
        n = self.ndof - len(self.free_dofs)
        return np.zeros(n), np.zeros(n)

    def step(self, mu) -> StepResult:
        """Reduced state at the contact position of ``mu`` (see :mod:`.online`)."""
        c, status, msg, lam = locate(self.vademecum, mu, self.name, need_S=self.projection != "srb")
        if c is None:
            return StepResult(None, "failed", msg, mu=dict(mu))
        B = self.basis[c.rows if c.block is None else c.block]  # the basis rows the load touches
        if self.proj is None:
            q = c.S_p * lam
        else:
            q = np.dot(c.values, B)  # Phi^T f
            if self.projection == "prb":  # beta of eq. 14, times S(s_p)
                q *= self.proj.gamma
                q = np.dot(self.proj._inv, q)
                q *= c.S_p
            if lam != 1.0:
                q *= lam
        u_c = np.dot(B, q)  # displacement at the loaded dofs (tool tip)
        return StepResult(q, status, msg, {"contact_displacement": u_c, "parameter_index": c.index}, mu)

    def floor_ops(self):
        """At a contact inside the domain: the parameter functions there (prb, vademecum), the
        projection of the load on the basis rows it touches, the contact displacement and the
        output product."""
        fam, vad = self.vademecum.family, self.vademecum
        j = fam.n_parameters // 2
        rows, vals = fam.load_at(fam.coords[j] if fam.kind == "line" else fam.nodes[j])
        B = np.ascontiguousarray(self.basis[rows])
        w, S2 = np.array([0.5, 0.5]), np.ascontiguousarray(vad.S[j:j + 2] if j + 2 <= len(vad.S) else vad.S[-2:])
        r = self.basis.shape[1]
        q, S_p, uc = np.empty(r), np.empty(vad.S.shape[1]), np.empty(len(rows))
        C_r = getattr(self, "_outputs", (None, None, None))[2]
        y = np.empty(0 if C_r is None else C_r.shape[0])
        proj = self.proj

        def floor():
            if self.projection != "srb":
                np.dot(w, S2, out=S_p)
            if proj is None:
                np.multiply(S_p, 1.0, out=q)
            elif self.projection == "srb":
                np.dot(vals, B, out=q)
            else:
                np.dot(proj._inv, proj.gamma * (vals @ B), out=q)
                q.__imul__(S_p)
            np.dot(B, q, out=uc)
            if C_r is not None:
                np.dot(C_r, q, out=y)
        return floor
