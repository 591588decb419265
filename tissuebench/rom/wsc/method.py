"""``"wsc"``: the weighted-skinning + cubature ROM as a registered trajectory method.

Offline (:meth:`Wsc.build`): handles by furthest-point sampling, skinning weights, the
subspace and its Dirichlet part, the cubature rule (``bgbc``, the paper's, and ``rbf``, ours,
without snapshots; ``nnls`` from training trajectories; ``full``), the reduced mass ``U^T M U`` and the reduced loads.
Online (:class:`WscModel`): ``start`` projects the initial state and factorises the step
matrix for ``dt``; ``step({"time", "load_factor"})`` advances one implicit step in the
subspace; the step result carries the full reduced vector ``q`` (``u = U q``, prescribed
values included).
"""
from __future__ import annotations

import time

import numpy as np

from ...reference.formulation import formulation_of
from ..base import Applies, RomMethod, Training, check_choice, register
from .cubature import bgbc_cubature, cell_centroids, full_cubature, rbf_cubature
from .handles import furthest_point_sampling, resolve_count
from .loads import ReducedLoads
from .nnls import nnls_cubature
from .reduced import CubatureForces
from .linsolve import KINDS, PRECISIONS
from .stepper import HISTORIES, PREDICTORS, SCHEMES, SOLVERS, ReducedStepper, make_scheme
from .model import WscModel
from .subspace import Subspace
from .weights import skinning_weights

__all__ = ["Wsc", "WscModel", "CUBATURES"]

CUBATURES = ("bgbc", "rbf", "nnls", "full")


def _positive(name, value, integer=False):
    ok = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)
    if not ok or not np.isfinite(value) or value <= 0 or (integer and int(value) != value):
        kind = "an integer >= 1" if integer else "a finite number > 0"
        raise ValueError(f"wsc option {name} must be {kind}, got {value!r}")
    return int(value) if integer else float(value)


@register
class Wsc(RomMethod):
    """Weighted skinning subspace + cubature, implicit dynamics (wsc-skinning-cubature).

    Options
    -------
    handles : int or float
        Number of free handles, or a fraction in (0, 1) of the mesh vertices (paper: 1-5 %).
    support : float
        Skinning support radius in units of the handles' covering radius (> 1).
    boundary_support : float
        Support of the boundary (Dirichlet) handles' kernel, distance to their set, in the
        same unit (default 0.1: about the set alone; with the full support the boundary
        handle -- 3 free dofs on a planar face -- dominates the layers next to the face
        and the subspace cannot follow the deformation there: projection error of the ci
        tension history with 10 handles 2.5 % against 0.5 %).
    cubature : {"bgbc", "rbf", "nnls", "full"}
        Cubature rule (see :mod:`.cubature`, :mod:`.nnls`): ``bgbc`` the paper's (biharmonic
        coordinates, libigl; at least 4 sample elements), ``rbf`` ours (normalised radial basis
        functions), ``nnls`` fitted to training forces, ``full`` every element.
    cubature_elements : int or float
        Sample elements (budget), or a fraction of the elements (paper: 5-7.5 %).
    cubature_support : float
        ``rbf`` weight-function radius in units of the samples' covering radius (> 1).
    nnls_tol : float or None
        Largest accepted relative fit error of the NNLS rule on held-out snapshots (None:
        any, reported only).
    integrator : {"backward_euler", "newmark", "hht"}
        Reduced time integrator (the paper's: backward Euler); ``alpha`` for HHT.
    solver : {"lbfgs", "newton"}
    rtol, max_iter, memory : Newton/L-BFGS tolerance, iteration cap, L-BFGS pairs.
    linear_solver : {"auto", "dense", "cholesky", "sparse"}
        Solves with the step matrix (:mod:`.linsolve`; auto: the fastest, timed at build).
    solve_precision : {"single", "double"}
        Of the dense step-matrix operator (single: accepted when it recovers seeded solutions to
        1e-2; it preconditions, the residuals stay in double).
    predictor : {"explicit", "linearised"}
        Start of the L-BFGS iteration (:mod:`.stepper`): the explicit Taylor predictor, or one
        linearised Newton step from the last state (one solve, no evaluation).
    lbfgs_history : {"step", "run"}
        L-BFGS pairs kept within a step, or carried from one step to the next.
    on_max_iter : {"fail", "accept"}
        A step that reaches ``max_iter`` fails (default), or is kept with its residual
        reported (``info["converged"] = False``): the paper stops its iteration "when the
        residual decreases to a desired threshold, or after exceeding a maximum number of
        iterations".
    track_energy : bool
        Kinetic and strain energy and the support work in every step's info (energy drift).
    seed : int
        Seed of the first handle and the first sample element.
    """

    name = "wsc"
    kind = "trajectory"
    nested = ()
    training_kinds = ("operators", "trajectory")
    applies = Applies()  # the default, declared: any finite-element scene

    @classmethod
    def why_not(cls, scene, options=None) -> str:
        """Besides :attr:`applies`: the cubature samples cell energies and forces, which the average
        nodal pressure formulation of a nearly incompressible scene's reference does not have."""
        why = super().why_not(scene, options)
        if why or not getattr(scene, "is_fe", False):
            return why
        if formulation_of(scene).name == "anp":
            return ("the reference uses average nodal pressure tetrahedra (nearly incompressible: P1 locks), whose "
                    "energy does not split into cell energies for the cubature to sample")
        return ""

    def __init__(self, handles=0.03, support=2.0, cubature="bgbc", cubature_elements=0.0625,
                 cubature_support=2.0, nnls_tol=0.05, integrator="backward_euler", alpha=-0.05,
                 solver="lbfgs", rtol=1e-6, max_iter=50, memory=8, linear_solver="auto",
                 on_max_iter="fail", boundary_support=0.1, track_energy=False, seed=0, solve_precision="single",
                 predictor="explicit", lbfgs_history="run"):
        if isinstance(handles, bool) or not isinstance(handles, (int, float, np.integer, np.floating)) \
                or not handles > 0:
            raise ValueError(f"wsc option handles must be a count >= 1 or a fraction in (0, 1), got {handles!r}")
        if isinstance(cubature_elements, bool) or not isinstance(cubature_elements, (int, float, np.integer,
                                                                                     np.floating)) \
                or not cubature_elements > 0:
            raise ValueError(f"wsc option cubature_elements must be a count >= 1 or a fraction in (0, 1), "
                             f"got {cubature_elements!r} (a zero budget integrates nothing)")
        _positive("boundary_support", boundary_support)
        for name, val in (("support", support), ("cubature_support", cubature_support)):
            if _positive(name, val) <= 1.0:
                raise ValueError(f"wsc option {name} = {val!r} must exceed 1 (a node may lie a covering radius "
                                 "away from every handle or sample)")
        for name, value, valid in (("cubature", cubature, CUBATURES), ("integrator", integrator, SCHEMES),
                                   ("solver", solver, SOLVERS), ("linear_solver", linear_solver, KINDS),
                                   ("solve_precision", solve_precision, PRECISIONS),
                                   ("predictor", predictor, PREDICTORS), ("lbfgs_history", lbfgs_history, HISTORIES),
                                   ("on_max_iter", on_max_iter, ("fail", "accept"))):
            check_choice("wsc option", name, value, valid)
        if nnls_tol is not None:
            _positive("nnls_tol", nnls_tol)
        self.scheme = make_scheme(integrator, alpha)
        self.options = dict(handles=handles, support=float(support), cubature=cubature,
                            cubature_elements=cubature_elements, cubature_support=float(cubature_support),
                            nnls_tol=nnls_tol, integrator=integrator, alpha=alpha, solver=solver,
                            rtol=_positive("rtol", rtol), max_iter=_positive("max_iter", max_iter, True),
                            memory=_positive("memory", memory, True), linear_solver=linear_solver,
                            on_max_iter=on_max_iter, boundary_support=float(boundary_support),
                            track_energy=bool(track_energy), seed=int(seed), solve_precision=solve_precision,
                            predictor=predictor, lbfgs_history=lbfgs_history)

    # ------------------------------------------------------------------ offline
    def build(self, training: Training) -> "WscModel":
        o = self.options
        be = training.backend
        if be is None:
            raise ValueError("wsc.build: training.backend is required (element kernels, mass, loads)")
        pb = be.problem
        timings, tic = {}, time.perf_counter()
        mesh = pb.mesh
        vertices = mesh.points
        groups = _dirichlet_groups(pb)
        group_vertices = [g[g < mesh.n_vertices] for g in groups]
        n_free_vertices = mesh.n_vertices - len(np.unique(np.concatenate(group_vertices))) if groups else \
            mesh.n_vertices
        k = resolve_count(o["handles"], mesh.n_vertices, "handles")
        if k > n_free_vertices:
            raise ValueError(f"handles = {o['handles']!r} ({k}) exceeds the {n_free_vertices} vertices outside the "
                             "Dirichlet sets")
        # the Dirichlet sets are never picked but do not repel the handles: a handle next to a
        # clamped face carries the steep gradient there (LV ci, 50 handles: projection error
        # of the inflation 3.4 % against 4.9 % with the sets as already-picked points)
        fps = furthest_point_sampling(vertices, k, o["seed"], sources=group_vertices, sources_as_picks=False)
        timings["handles_s"] = time.perf_counter() - tic
        tic = time.perf_counter()
        # every vertex a handle (covering radius 0): any radius interpolates; half the separation
        radius = o["support"] * (fps.covering_radius if fps.covering_radius > 0 else 0.5 * fps.separation)
        W = skinning_weights(pb.nodes, vertices[fps.indices], radius, groups,
                             o["boundary_support"] * radius / o["support"])
        sub = Subspace(pb.nodes, W, len(groups), pb.fixed_dofs)
        _check_prescribed_affine(sub, pb)
        M = be.mass()
        timings["weights_s"] = time.perf_counter() - tic
        tic = time.perf_counter()
        budget = resolve_count(o["cubature_elements"], mesh.n_cells, "cubature_elements")
        cub = self._cubature(o, budget, be, sub, training)
        timings["cubature_s"] = time.perf_counter() - tic
        tic = time.perf_counter()
        M_q = sub.reduced_matrix(M)
        loads = ReducedLoads(sub, be)
        forces = CubatureForces(sub, be, cub)
        stepper = ReducedStepper(sub, forces, M_q, loads, self.scheme, o["solver"], o["rtol"], o["max_iter"],
                                 o["memory"], o["linear_solver"], accept_unconverged=o["on_max_iter"] == "accept",
                                 precision=o["solve_precision"], predictor=o["predictor"],
                                 history=o["lbfgs_history"])
        timings["operators_s"] = time.perf_counter() - tic
        info = {"handles": k, "boundary_handles": len(groups), "n_q": sub.n_q, "n_z": sub.n_z,
                "covering_radius": fps.covering_radius, "separation": fps.separation, "support_radius": radius,
                "cubature": cub.scheme, "cubature_elements": cub.size, "cubature_info": cub.info,
                "offline": timings, "handle_vertices": fps.indices,
                "mesh": {"vertices": mesh.n_vertices, "cells": mesh.n_cells}}
        model = WscModel(sub, stepper, pb, info, M, track_energy=o["track_energy"], dt=training.dt,
                         envelope=_envelope(training) if cub.scheme == "nnls" else {})
        info["linear_solver"] = o["linear_solver"]  # the kind built, once start has factorised (model.start)
        if o["solver"] == "lbfgs" and training.dt is not None:  # factorised offline, at rest (start reuses it)
            H, _ = stepper.step_matrix(training.dt, sub.q_of(np.zeros(sub.n_z), model.prescribed_q(0.0)))
            info["step_matrix"], info["linear_solver"] = H.info, H.kind
        if training.outputs:
            model.attach_outputs(training.outputs)
        return model

    def _cubature(self, o, budget, be, sub, training):
        pb = be.problem
        if o["cubature"] == "full":
            return full_cubature(pb.mesh.n_cells)
        volumes = be.cell_kernel().volumes
        if o["cubature"] == "bgbc":
            if pb.mesh.cell_type != "tetra":
                raise ValueError(f"wsc cubature = 'bgbc' needs a tetrahedral mesh (libigl's biharmonic coordinates), "
                                 f"got {pb.mesh.cell_type!r}; use cubature = 'rbf'")
            if budget < 4:
                raise ValueError(f"wsc cubature = 'bgbc' needs cubature_elements >= 4 (affine functions must be "
                                 f"pinned), got {o['cubature_elements']!r} ({budget} elements)")
            return bgbc_cubature(pb.mesh.points, pb.mesh.cells, volumes, budget, o["seed"])
        centroids = cell_centroids(pb.mesh.points, pb.mesh.cells)
        if o["cubature"] == "rbf":
            return rbf_cubature(centroids, volumes, budget, o["seed"], o["cubature_support"])
        return nnls_cubature(sub, be, training, budget, centroids, o["nnls_tol"], o["seed"])


def _dirichlet_groups(pb):
    """Node sets of the Dirichlet entries (a node constrained by several: the last one)."""
    owner = np.full(len(pb.nodes), -1)
    for g, d in enumerate(pb.dirichlet):
        dofs = d.resolve(pb.nodes)[0]
        owner[np.unique(dofs // 3)] = g
    return [np.flatnonzero(owner == g) for g in range(len(pb.dirichlet)) if np.any(owner == g)]


def _check_prescribed_affine(sub, pb):
    for lam in (0.5, 1.0):
        res = sub.constraint_residual(pb.prescribed_values(lam))
        if res > 1e-8:
            raise ValueError(f"wsc: the prescribed displacement at load factor {lam} is not affine on its Dirichlet "
                             f"set (relative residual {res:.2e}); the boundary handles cannot impose it")


def _envelope(training):
    if not training.parameters:
        return {}
    lam = training.parameter_values("load_factor")
    return {"load_factor": (float(lam.min()), float(lam.max()))}
