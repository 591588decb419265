"""``romtools_ecsw``: ECSW hyper-reduction by Pressio's romtools, on ``pod_galerkin``'s footing.

Pressio's ``romtools`` (rom-tools-and-workflows 0.2, https://pressio.github.io/rom-tools-and-workflows/)
computes the two things this method takes from it:

* the basis: ``romtools.vector_space.VectorSpaceFromPOD`` of the training's displacement snapshots on
  the free dofs (no shift, no scaling; truncated to ``n_modes``, or by ``EnergyBasedTruncater``);
* the element rule: ``romtools.hyper_reduction.ecsw.ecsw_fixed_test_basis`` with its NNLS
  (``ECSWsolverNNLS``, Chapman et al. 2016) on the element residuals of the training states, the
  test basis the rows of the POD basis at each element's dofs (the "mesh degrees of freedom" of
  romtools are the elements; the "variables" their local dofs).

The rest is ``pod_galerkin hyper = "ecsw"``'s: the same training states (at most ``hyper_states``,
evenly through the runs, projected on the basis; every fourth held out of the fit and its force error
reported, each state's rows scaled by its reduced force, as ``tissuebench/rom/galerkin/ecsw.py``
does), and the same online model (:func:`tissuebench.rom.galerkin_model`: the scene's
implicit integrator, Newton with the reduced tangent), so that only the element selection differs.
romtools has no time integrator of its own in Python (Pressio's are C++).

romtools prints (its NNLS a line per iteration, its energy truncater a mask) and its NNLS ends the
process (``sys.exit``) when its inner loop fails: the printing is captured (the NNLS's last line is
kept in ``info``), an exit fails the build.
"""
from __future__ import annotations

import contextlib
import io
import time

import numpy as np
from tissuebench.rom import Applies, OnlineModel, RomMethod, Training, element_kernel, galerkin_model, method_class

from ._common import evenly, fraction, missing, positive, positive_int

__all__ = ["RomtoolsEcsw"]


class RomtoolsEcsw(RomMethod):
    """POD-Galerkin with romtools' ECSW element rule (module docstring).

    Options
    -------
    n_modes : int or None
        Basis size (None: romtools' ``EnergyBasedTruncater(energy)``).
    energy : float in (0, 1]
        The energy criterion when ``n_modes`` is None.
    ecsw_tol : float
        romtools' ECSW tolerance: the largest relative residual of the fit (``pod_galerkin``'s ``ecsw_tol``).
    hyper_states : int
        At most this many training states fit the rule (``pod_galerkin``'s).
    integrator, rtol, max_iterations, newton_tangent
        The online model's (``pod_galerkin``'s options of the same names).
    """

    name = "romtools_ecsw"
    kind = "trajectory"
    training_kinds = ("trajectory",)
    applies = Applies(dead_loads=True)
    counterpart = ("pod_galerkin", {"hyper": "ecsw"})

    def __init__(self, n_modes=None, energy=0.99999, ecsw_tol=5e-3, hyper_states=60, integrator=None, rtol=1e-6,
                 max_iterations=20, newton_tangent="reuse"):
        who = "romtools_ecsw"
        self.options = dict(n_modes=positive_int(who, "n_modes", n_modes, True), energy=fraction(who, "energy", energy),
                            ecsw_tol=positive(who, "ecsw_tol", ecsw_tol),
                            hyper_states=positive_int(who, "hyper_states", hyper_states))
        # checked by the online model's own options (pod_galerkin's): named there
        self.stepping = dict(integrator=integrator, rtol=rtol, max_iterations=max_iterations,
                             newton_tangent=newton_tangent)

    @classmethod
    def unavailable(cls) -> str:
        return missing("romtools")

    @classmethod
    def why_not(cls, scene, options=None) -> str:
        """Besides :attr:`applies`: the element rule and the online model are ``pod_galerkin``'s, so
        what refuses it refuses this (a reference whose force has no element split)."""
        return super().why_not(scene, options) or method_class("pod_galerkin").why_not(scene)

    def build(self, training: Training) -> OnlineModel:
        if training.snapshots is None or training.system is None or training.dt is None:
            raise ValueError("romtools_ecsw.build: needs a trajectory training (snapshots, backend, system, dt)")
        from romtools.vector_space import VectorSpaceFromPOD
        from romtools.vector_space.utils.truncater import BasisSizeTruncater, EnergyBasedTruncater

        o, tic = self.options, time.perf_counter()
        system = training.system
        free, fixed = np.asarray(system.free), np.asarray(system.fixed)
        snapshots = training.snapshots[free][None].copy()  # romtools' (variables, points, samples), shifted in place
        truncater = BasisSizeTruncater(o["n_modes"]) if o["n_modes"] else EnergyBasedTruncater(o["energy"])
        with contextlib.redirect_stdout(io.StringIO()):  # romtools' energy truncater prints its mask
            V = np.ascontiguousarray(VectorSpaceFromPOD(snapshots, truncater=truncater).get_basis()[0])
        info = {"library": "romtools", "n_modes": int(V.shape[1]), "basis_s": time.perf_counter() - tic}
        tic = time.perf_counter()
        cells, weights, info["hyper"] = self._rule(training, V, free, fixed)
        info["hyper"]["offline_s"] = time.perf_counter() - tic
        return galerkin_model(training, V, cells, weights, name=self.name, info=info, **self.stepping)

    def _rule(self, training, V, free, fixed):
        """``(cells, weights, info)``: romtools' ECSW on the training states (module docstring)."""
        from romtools.hyper_reduction.ecsw import ECSWsolverNNLS, ecsw_fixed_test_basis

        o, S, system = self.options, training.snapshots, training.system
        kernel = element_kernel(training)
        basis_full = np.zeros((S.shape[0], V.shape[1]))
        basis_full[free] = V
        test = basis_full[kernel.dofs]  # (m, n_loc, r): V_e, zero on the fixed dofs
        states, scales = [], []
        for c in evenly(S.shape[1], o["hyper_states"]):
            u = basis_full @ (V.T @ S[free, c])  # the state projected on the basis, as pod_galerkin fits on
            if system.has_prescribed:
                u[fixed] = S[fixed, c]
            fe = kernel.forces(kernel.gather(u))  # (m, n_loc)
            b = np.einsum("ek,ekr->r", fe, test)  # the reduced force
            states.append(fe)
            scales.append(float(np.linalg.norm(b)))
        scales = np.array(scales)
        use = [k for k in range(len(states)) if scales[k] > 1e-12 * max(scales.max(initial=0.0), 1e-300)]
        if len(use) < 2:
            raise ValueError(f"romtools_ecsw: {len(use)} training state(s) with a force; needs at least 2")
        held = use[3::4] if len(use) >= 4 else []
        train = [k for k in use if k not in held]
        # romtools' layout: residuals (variables = local dofs, mesh entities = elements, samples), each state's
        # rows scaled by its reduced force (pod_galerkin's ECSW rows; romtools leaves scaling to the caller)
        residuals = np.stack([states[k].T / scales[k] for k in train], axis=2)
        test_basis = np.ascontiguousarray(test.transpose(1, 0, 2))
        printed = io.StringIO()
        tic = time.perf_counter()
        try:
            with contextlib.redirect_stdout(printed):
                cells, weights = ecsw_fixed_test_basis(ECSWsolverNNLS(), residuals, test_basis, test.shape[1],
                                                       o["ecsw_tol"])
        except SystemExit as exc:
            lines = printed.getvalue().strip().splitlines()
            raise ValueError(f"romtools_ecsw: romtools' NNLS exited ({exc}); last line: "
                             f"{lines[-1] if lines else ''}") from None
        fit_s = time.perf_counter() - tic
        cells, weights = np.asarray(cells, dtype=np.int64), np.asarray(weights, float)
        keep = weights > 0
        cells, weights = cells[keep], weights[keep]
        residual = _residual(residuals, test_basis, cells, weights)
        errors = [_residual((states[k].T / scales[k])[:, :, None], test_basis, cells, weights) for k in held]
        lines = printed.getvalue().strip().splitlines()
        info = {"scheme": "ecsw", "solver": "romtools ECSWsolverNNLS", "elements": int(len(cells)),
                "candidates": int(kernel.dofs.shape[0]), "training_states": len(train), "heldout_states": len(held),
                "train_residual": residual, "heldout_force_error": max(errors) if errors else float("nan"),
                "tol": o["ecsw_tol"], "fit_s": fit_s, "nnls_iterations": len(lines),
                "nnls_last_line": lines[-1] if lines else ""}
        return kernel.cells[cells], weights, info


def _residual(residuals, test_basis, cells, weights) -> float:
    """``|A w - b| / |b|`` of the rule on residual snapshots (variables, elements, samples)."""
    G = np.einsum("ves,ver->esr", residuals, test_basis)  # (elements, samples, r): V_e^T r_e
    b = G.sum(axis=0)
    approx = np.einsum("e,esr->sr", weights, G[cells])
    return float(np.linalg.norm(approx - b) / max(np.linalg.norm(b), 1e-300))
