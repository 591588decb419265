"""``"pgd_cutting"``: PGD vademecum + cracking-node enrichment, the coupled system (28) of
pgd-vademecum-cutting §4.3, on one incision of the scene's ``[cut]``.

Offline: the vademecum of the scalpel contact over the accessible strip (or the whole
anterior surface), the srb or prb reduced stiffness, the enrichment operators of the
strip (:mod:`.enrichment`) projected on the modes, i.e. every block of

    [ K_bb   K_bq ] [beta]   [f_b(s_p)]          srb: K_bb = Phi^T K Phi = I, K_bq = Phi^T K_ud, K_qq = K_dd
    [ K_qb   K_qq ] [ q  ] = [   0    ]          prb: K_bb = alpha ∘ X^T K X, K_bq = diag(gamma) X^T K_ud,
                                                      K_qq = |S| K_dd (doubly weak form, eq. 24-26)

for the longest cut. Linear elasticity (small strain about the intact cornea, the
tangent at u = 0 of the SVK material), as the paper's system (28).

Online, ``step({"position": j, "cut_length": c})`` (position: :mod:`.online`; cut
length: :mod:`.strip`): when the cut has advanced to a length never reached before, the
new cracked nodes are enriched on the fly: the inverse of the coupled matrix is extended
by a Schur complement (O(n^2 k) for k new dofs; n <= N + 3 x cracked nodes) and kept per
length; then ``x = M_c^{-1} b``. The contact force of the step (``force_x, force_y,
force_z`` in N, default ``load_factor`` x the scene's contact force) is split into the
parts normal and parallel to the surface at the contact; ``info["cuts"]`` says whether
|F_parallel| > F_cut (the cutting criterion of §3; the study drives the cut length
itself). No full-size vector is touched; :meth:`reconstruct` returns the field on the
mesh cut to length c (:func:`~.enrichment.to_cut_mesh`).
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from ..base import Applies, OnlineModel, RomMethod, StepResult, Training, register
from .enrichment import Enrichment, condense, enrichment_operators, to_cut_mesh
from .linear import check_pgd_options
from .online import LocatedContact, locate
from .projections import make_projection
from .strip import incision_strip
from .training import family_from_training, scene_of, uncut_backend
from .vademecum import Vademecum, build_vademecum

__all__ = ["CuttingModel", "PgdCutting"]


class CuttingModel(LocatedContact, OnlineModel):
    """Online coupled system (module docstring); ``q = [coefficients on the basis; d]``
    with the coefficients on X at s_p for prb (``beta ∘ S(s_p)``)."""

    kind = "map"

    def __init__(self, name, vademecum: Vademecum, projection: str, enrichment: Enrichment, F_cut: float,
                 points: np.ndarray, problem=None):
        self.name, self.vademecum, self.projection = name, vademecum, projection
        self.enrichment, self.strip, self.F_cut, self.problem = enrichment, enrichment.strip, float(F_cut), problem
        proj = make_projection(projection, vademecum)
        self.proj, self.basis = proj, proj.basis
        fam = vademecum.family
        self.free_dofs, self.ndof, self.force = fam.free_dofs, fam.ndof, np.asarray(fam.force, float)
        r = self.basis.shape[1]
        K_bq, K_qq, self._G_rows = self.basis.T @ enrichment.K_ud, enrichment.K_dd, None
        if enrichment.G is not None:  # condensed: psi = N H - G (enrichment.py)
            G = enrichment.G
            K_bq = K_bq - (fam.K @ self.basis).T @ G  # = 0 up to round-off
            K_qq = K_qq - enrichment.K_ud.T @ G
            self._G_rows = G  # rows at the contact give the load of psi: -G[rows]^T F
        self._gamma, self._S_measure = None, 1.0
        # prb, the doubly weak form: the enrichment does not depend on s, its s-integrals are gamma and |S|
        if projection == "prb":
            self._gamma, self._S_measure = proj.gamma, float(fam.weights.sum())
            K_bq, K_qq = proj.gamma[:, None] * K_bq, self._S_measure * K_qq
        n_e = K_qq.shape[0]
        self.M = np.zeros((r + n_e, r + n_e))
        self.M[:r, :r], self.M[:r, r:], self.M[r:, :r], self.M[r:, r:] = proj.K_r, K_bq, K_bq.T, K_qq
        self.M = 0.5 * (self.M + self.M.T)
        self.r = r
        lam, V = np.linalg.eigh(proj.K_r)
        keep = lam > 1e-12 * lam.max()  # (pseudo-)inverse: prb's K_bb may be singular for dependent modes
        self._inv = {0: (V[:, keep] / lam[keep]) @ V[:, keep].T}  # inverse of the coupled matrix per cut length
        self._contacts = {}  # node -> what a step there reads (_contact)
        self.points = points
        self._c = 0

    # ------------------------------------------------------------------ sizes
    @property
    def n_reduced(self) -> int:
        return self.r + 3 * int(self.strip.n_enriched[self._c])

    # ------------------------------------------------------------------ hooks of the harness (base.py)
    def contact_nodes(self) -> np.ndarray | None:
        """The accessible strip's nodes (the vademecum's parameter nodes)."""
        return self.vademecum.family.nodes

    def incision_strip(self):
        return self.strip

    def contact_force(self) -> np.ndarray:
        return self.force

    @property
    def envelope(self) -> dict:
        return {"position": (0, self.vademecum.family.n_parameters - 1), "cut_length": (0, self.strip.max_cut_length)}

    @property
    def info(self) -> dict:
        """Record of the offline build (the sweep's ``model_info``)."""
        return {**self.vademecum.build_info(), "projection": self.projection, "enrichment": self.enrichment.kind,
                "max_cut_length": self.strip.max_cut_length, "enriched_nodes": len(self.strip.enriched),
                "enrichment_K_uu_check": self.enrichment.K_uu_check, "F_cut_N": self.F_cut}

    # ------------------------------------------------------------------ enrichment on the fly
    def _inverse(self, c: int) -> np.ndarray:
        """``M_c^{-1}``, extended from the longest known shorter cut by Schur complements."""
        inv = self._inv.get(c)
        if inv is not None:
            return inv
        k = max(k for k in self._inv if k < c)
        Minv, n0 = self._inv[k], self.r + 3 * int(self.strip.n_enriched[k])
        n1 = self.r + 3 * int(self.strip.n_enriched[c])
        B, D = self.M[:n0, n0:n1], self.M[n0:n1, n0:n1]
        Z = Minv @ B
        S_inv = np.linalg.inv(D - B.T @ Z)
        ZS = Z @ S_inv
        out = np.empty((n1, n1))
        out[:n0, :n0] = Minv + ZS @ Z.T
        out[:n0, n0:] = -ZS
        out[n0:, :n0] = -ZS.T
        out[n0:, n0:] = S_inv
        self._inv[c] = out
        return out

    def start(self, mu0=None, state0=None, dt=None) -> None:
        """Forget the enrichment built online (the next cut re-enriches from the intact state)."""
        self._inv = {0: self._inv[0]}
        self._c = 0

    # ------------------------------------------------------------------ step
    def _force(self, mu, lam):
        keys = ("force_x", "force_y", "force_z")
        if "force_x" in mu or "force_y" in mu or "force_z" in mu:
            F = np.array([float(mu.get(k, 0.0)) for k in keys])
            if not np.all(np.isfinite(F)):
                raise ValueError(f"{self.name}.step: non-finite contact force {F.tolist()}")
            return F
        return lam * self.force

    def _contact(self, node: int):
        """What a step at ``node`` reads, prepared at its first visit: the free rows of its three
        dofs, which of the three are free, those basis rows and enrichment-correction rows, the
        outward normal."""
        entry = self._contacts.get(node)
        if entry is None:
            rows = self.vademecum.family.free_index[3 * node + np.arange(3)]
            keep = rows >= 0
            rows = rows[keep]
            G = None if self._G_rows is None else np.ascontiguousarray(self._G_rows[rows])
            n = self.strip.normal(self.points, node)
            entry = self._contacts[node] = (rows, keep if not keep.all() else None,
                                            np.ascontiguousarray(self.basis[rows]), G, n, tuple(map(float, n)))
        return entry

    def step(self, mu) -> StepResult:
        """Coupled reduced solve at the contact position and cut length of ``mu``."""
        if "cut_length" not in mu:
            raise ValueError(f"{self.name}.step: parameter 'cut_length' missing from mu = {dict(mu)}")
        c = mu["cut_length"]
        if not (type(c) is int and 0 <= c <= self.strip.max_cut_length):
            c = self.strip.check_length(c)
        ct, status, msg, lam = locate(self.vademecum, mu, self.name, need_S=self.projection == "prb")
        if ct is None:
            return StepResult(None, "failed", msg, mu=dict(mu))
        F = self._force(mu, lam)
        node = int(ct.where)
        rows, keep, B, G, n, nf = self._contact(node)
        Fv = F if keep is None else F[keep]
        Minv = self._inv.get(c)
        if Minv is None:
            Minv = self._inverse(c)
        self._c = c
        b = np.zeros(Minv.shape[0])
        r = self.r
        b[:r] = np.dot(Fv, B) if self._gamma is None else self._gamma * np.dot(Fv, B)
        if G is not None and c:
            b[r:] = -self._S_measure * np.dot(Fv, G[:, :len(b) - r])
        x = np.dot(Minv, b)
        if ct.S_p is not None and self.projection == "prb":
            x[:r] *= ct.S_p
        u_c = np.dot(B, x[:r])  # the contact node is a crack-front node: not enriched
        f0, f1, f2 = F.tolist()
        F_n = f0 * nf[0] + f1 * nf[1] + f2 * nf[2]
        F_par = math.sqrt((f0 - F_n * nf[0]) ** 2 + (f1 - F_n * nf[1]) ** 2 + (f2 - F_n * nf[2]) ** 2)
        info = {"cut_length": c, "contact_node": node, "contact_displacement": u_c, "F_normal": F_n,
                "F_parallel": F_par, "cuts": F_par > self.F_cut, "parameter_index": ct.index}
        return StepResult(x, status, msg, info, mu)

    def floor_ops(self):
        """At the crack tip of the longest cut: the load on the basis rows and on the enrichment
        corrections, the coupled solve (the product with the inverse kept for that length), the
        contact displacement."""
        c = self.strip.max_cut_length
        Minv = self._inverse(c)
        rows, keep, B, G, n, nf = self._contact(int(self.strip.tip(c)))
        F = self.force if keep is None else self.force[keep]
        r, n_all = self.r, Minv.shape[0]
        b, x, u_c = np.zeros(n_all), np.empty(n_all), np.empty(len(rows))
        Gc = None if G is None or not c else np.ascontiguousarray(G[:, :n_all - r])
        S_p = self.vademecum.S[0] if self.projection == "prb" else None

        def floor():
            np.dot(F, B, out=b[:r])
            if Gc is not None:
                np.dot(F, Gc, out=b[r:])
            np.dot(Minv, b, out=x)
            if S_p is not None:
                x[:r] *= S_p
            np.dot(B, x[:r], out=u_c)
        return floor

    def outputs(self, result: StepResult) -> dict:
        """Contact displacement (mm) and the parallel contact force (N) of a step."""
        if result.q is None:
            return {k: float("nan") for k in ("contact_ux", "contact_uy", "contact_uz", "F_parallel")}
        info = result.info
        keep = self._contact(info["contact_node"])[1]
        u = info["contact_displacement"].tolist()
        if keep is not None:
            it = iter(u)
            u = [next(it) if k else 0.0 for k in keep]
        return {"contact_ux": u[0], "contact_uy": u[1], "contact_uz": u[2], "F_parallel": info["F_parallel"]}

    def reconstruct(self, result: StepResult) -> np.ndarray:
        """Displacement on the mesh cut to the step's length (originals, then copies)."""
        if result.q is None:
            raise ValueError(f"{self.name}.reconstruct: the step failed ({result.message}); no state")
        c = int(result.info["cut_length"])
        u = np.zeros(self.ndof)
        d = result.q[self.r:]
        u[self.free_dofs] = self.basis @ result.q[:self.r]
        if self._G_rows is not None and len(d):
            u[self.free_dofs] -= self._G_rows[:, :len(d)] @ d
        return to_cut_mesh(u, d, self.strip, c)


@register
class PgdCutting(RomMethod):
    """PGD vademecum + cracking-node cutting on one incision of the scene's ``[cut]``.

    Options
    -------
    n_modes, projection ("srb" | "prb"), tol, max_fixed_point, fixed_point_tol, seed :
        of the vademecum (:class:`~.linear.Pgd`)
    incision : int, index in ``[cut].incisions`` (default 0)
    radii : [r0, r1] mm, optional, replaces the incision's radii
    accessible : "strip" (the incision's anterior nodes and ``strip_rings`` rings of
        neighbours: the vademecum's parameter domain) or "anterior" (the whole surface)
    strip_rings : int >= 0
    F_cut : float, N, threshold of the cutting criterion (default: the scene's
        ``[methods.pgd_cutting] F_cut_N``, else 3)
    enrichment : "cracking_node" (the paper's N_a H_+ functions) or "condensed" (each
        corrected by the intact response G = K^{-1} K_ud, :mod:`.enrichment`)
    """

    name = "pgd_cutting"
    kind = "map"
    training_kinds = ("operators",)
    applies = Applies(point_load=True, homogeneous_dirichlet=True, needs_cut=True, mesh_builders=("cornea_dome",),
                      linear_model=True)  # mu: node and cut_length (evaluation cut_lengths), not Scene.at keys

    def __init__(self, n_modes: int = 6, projection: str = "srb", incision: int = 0, radii=None,
                 accessible: str = "strip", strip_rings: int = 1, F_cut: float | None = None, tol: float = 1e-8,
                 max_fixed_point: int = 50, fixed_point_tol: float = 1e-8, seed: int = 0,
                 enrichment: str = "cracking_node"):
        check_pgd_options(self.name, n_modes, tol, max_fixed_point, fixed_point_tol, seed)
        if projection not in ("srb", "prb"):
            raise ValueError(f"{self.name}: projection = {projection!r}; valid: ['srb', 'prb']")
        if enrichment not in ("cracking_node", "condensed"):
            raise ValueError(f"{self.name}: enrichment = {enrichment!r}; valid: ['cracking_node', 'condensed']")
        if accessible not in ("strip", "anterior"):
            raise ValueError(f"{self.name}: accessible = {accessible!r}; valid: ['strip', 'anterior']")
        if isinstance(incision, bool) or not isinstance(incision, (int, np.integer)) or incision < 0:
            raise ValueError(f"{self.name}: incision must be an index >= 0, got {incision!r}")
        if isinstance(strip_rings, bool) or not isinstance(strip_rings, (int, np.integer)) or strip_rings < 0:
            raise ValueError(f"{self.name}: strip_rings must be an integer >= 0, got {strip_rings!r}")
        if radii is not None and not (len(radii) == 2 and 0 <= radii[0] < radii[1]):
            raise ValueError(f"{self.name}: radii = {radii!r}; expected [r0, r1] with 0 <= r0 < r1 (mm)")
        if F_cut is not None and not (np.isfinite(F_cut) and F_cut > 0):
            raise ValueError(f"{self.name}: F_cut must be a force > 0 (N), got {F_cut!r}")
        self.n_modes, self.projection, self.incision, self.radii = int(n_modes), projection, int(incision), radii
        self.accessible, self.strip_rings, self.F_cut, self.enrichment = accessible, int(strip_rings), F_cut, enrichment
        self.tol, self.max_fixed_point, self.fixed_point_tol, self.seed = tol, max_fixed_point, fixed_point_tol, seed

    def strip(self, training: Training):
        """(scene, intact backend, IncisionStrip) of the training's scene."""
        scene = scene_of(training, self.name)
        if scene.cut is None:
            raise ValueError(f"{self.name}: scene {scene.name!r} has no [cut] table (no incision to follow)")
        incs = scene.cut["incisions"]
        if self.incision >= len(incs):
            raise ValueError(f"{self.name}: incision = {self.incision}; the scene has {len(incs)} incision(s)")
        inc = dict(incs[self.incision])
        if self.radii is not None:
            inc["radii"] = [float(r) for r in self.radii]
        be = uncut_backend(training, scene, self.name)
        intact = dataclasses.replace(scene, cut=None)
        st = incision_strip(intact.mesh, intact.mesh_info, inc, scene.cut["depth_fraction"], be.problem.free_dofs,
                            self.strip_rings)
        return scene, be, st

    def build(self, training: Training) -> OnlineModel:
        scene, be, st = self.strip(training)
        info = dict(training.info or {})
        if self.accessible == "strip":
            info["accessible_nodes"] = st.accessible
        fam = family_from_training(Training(backend=be, scene=training.scene, info=info), self.name)
        vad = build_vademecum(fam, self.n_modes, self.tol, self.max_fixed_point, self.fixed_point_tol, self.seed)
        F_cut = self.F_cut or float(scene.paper.get("methods", {}).get("pgd_cutting", {}).get("F_cut_N", 3.0))
        enr = enrichment_operators(scene, be, st)
        if self.enrichment == "condensed":
            enr = condense(enr, fam.K)
        return CuttingModel(self.name, vad, self.projection, enr, F_cut, be.problem.nodes, be.problem)
