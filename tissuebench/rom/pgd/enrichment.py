"""Cracking-node enrichment of the incision strip (pgd-vademecum-cutting §4.2, eq. 23).

A cracked node ``a`` carries, besides its usual dofs, the enrichment ``N_a(x) H_+(x) d_a``
with ``N_a`` its FE shape function and ``H_+`` the Heaviside function of the incision
plane (1 on the counter-clockwise side, 0 on the other). The crack passes through the
node along the element faces (the incision follows mesh faces), so this is the cracking
node method of Song & Belytschko with its crack segments on element boundaries, and the
enriched space is **exactly** the FE space of the mesh cut by node duplication
(:mod:`tissuebench.cases.cutting`): the duplicated node's copy (used by the cells on the
counter-clockwise side) carries ``u_copy = u_a + d_a``. The crack front is not enriched.

With ``T`` that change of variables (``u_cut = T [u; d]``), the enriched stiffness is
``T^T K_cut T``: its ``u``-``u`` block is the intact stiffness K, the coupling ``K_ud`` and
the ``d``-``d`` block ``K_dd`` come from the cells on the counter-clockwise side only. They
are computed once, offline, for the longest cut of the strip; a shorter cut uses the
leading columns (the enriched dofs are ordered by cut order, node-major, xyz).

**Condensed variant** (not in the paper; :func:`condense`): with a Ritz basis Phi for the
continuous part, the plain enrichment leaves the change of the continuous field caused by
the cut to Phi, which spans responses of the *intact* cornea; the error then grows with
the cut length (measured: 2 % to 25 % at paper resolution, even with all 36 strip modes).
Replacing each enrichment function by ``psi_k = N_k H_+ - G_k`` with
``G = K^{-1} K_ud`` (the intact body's response to the enrichment's coupling forces,
3 solves per cracked node of the strip, offline) makes the blocks exact static
condensation: ``a(Phi, psi) = Phi^T (K_ud - K G) = 0``, ``a(psi, psi) = K_dd - K_ud^T G``
(the Schur complement), load ``psi^T f = -G^T f``. The system keeps the size of (28), the
jump d is the FE one, and the error of the cut model is that of the vademecum at the
contact alone.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from ...refsolvers import make_backend
from ...refsolvers.sparse_direct import factorized
from .strip import IncisionStrip

__all__ = ["Enrichment", "enrichment_operators", "condense", "to_cut_mesh"]


@dataclass(eq=False)
class Enrichment:
    """Operators of the enrichment on the intact mesh's free dofs (module docstring).

    Attributes
    ----------
    K_ud : (n_free, n_e) sparse CSC, coupling of the continuous and enriched dofs
    K_dd : (n_e, n_e) dense, enriched-enriched stiffness
    K_uu_check : float, ``max |K_uu - K| / max |K|`` (should be round-off: the intact
        stiffness is recovered from the cut mesh)
    strip : IncisionStrip
    G : (n_free, n_e) array or None, ``K^{-1} K_ud`` of the condensed variant (:func:`condense`)
    """

    K_ud: sp.csc_matrix
    K_dd: np.ndarray
    K_uu_check: float
    strip: IncisionStrip
    G: np.ndarray | None = None

    @property
    def kind(self) -> str:
        return "cracking_node" if self.G is None else "condensed"

    @property
    def n_enriched_dofs(self) -> np.ndarray:
        """(M,) enriched dofs at each cut length."""
        return 3 * self.strip.n_enriched


def _transform(n_orig_dofs, n_cut_dofs, enriched, copies):
    """``T`` (n_cut_dofs, n_orig_dofs + 3 len(enriched)) with ``u_cut = T [u; d]``."""
    comp = np.arange(3)
    a = (3 * np.asarray(enriched)[:, None] + comp).ravel()
    b = (3 * np.asarray(copies)[:, None] + comp).ravel()
    k = n_orig_dofs + np.arange(len(a))
    rows = np.concatenate([np.arange(n_orig_dofs), b, b])
    cols = np.concatenate([np.arange(n_orig_dofs), a, k])
    return sp.csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(n_cut_dofs, n_orig_dofs + len(a)))


def enrichment_operators(scene, backend, strip: IncisionStrip) -> Enrichment:
    """Enrichment operators of the longest cut of ``strip``.

    Parameters
    ----------
    scene : Scene (the cornea scene; its Dirichlet sets and material are reused)
    backend : Backend of the intact mesh (its class assembles the cut mesh too)
    strip : IncisionStrip
    """

    c = strip.max_cut_length
    if c < 1:
        raise ValueError("enrichment_operators: the strip allows no cut (fewer than three nodes on the incision)")
    cut_scene = dataclasses.replace(scene, cut={"incisions": [strip.incision(c)],
                                                "depth_fraction": strip.depth_fraction})
    cut_be = make_backend(type(backend), dataclasses.replace(cut_scene.to_problem(), loads=()))
    K_cut = cut_be.tangent(np.zeros(cut_be.ndof))
    n_od = backend.ndof
    T = _transform(n_od, cut_be.ndof, strip.enriched, strip.copies[c])
    K_enr = (T.T @ K_cut @ T).tocsc()
    K = backend.tangent(np.zeros(n_od))
    diff = abs(K_enr[:n_od, :n_od] - K).max()
    free = np.asarray(backend.problem.free_dofs)
    return Enrichment(K_enr[free][:, n_od:].tocsc(), K_enr[n_od:, n_od:].toarray(), float(diff / abs(K).max()), strip)


def condense(enrichment: Enrichment, K) -> Enrichment:
    """The condensed variant (module docstring): ``G = K^{-1} K_ud`` with ``K`` the intact
    stiffness on the free dofs (sparse; factorised here, one solve per enriched dof)."""

    G = factorized(sp.csr_matrix(K))(np.asarray(enrichment.K_ud.toarray()))
    return Enrichment(enrichment.K_ud, enrichment.K_dd, enrichment.K_uu_check, enrichment.strip, G)


def to_cut_mesh(u_orig: np.ndarray, d: np.ndarray, strip: IncisionStrip, c: int) -> np.ndarray:
    """Full displacement on the mesh cut to length ``c`` (node ids of
    :func:`~tissuebench.cases.cutting.cut_mesh`: originals, then the copies) from the
    intact-mesh dofs ``u_orig`` (n_orig_dofs,) and the enrichment ``d`` (3 n_enriched[c],)."""
    n = int(strip.n_enriched[c])
    if d.shape != (3 * n,):
        raise ValueError(f"to_cut_mesh: d has shape {d.shape}, cut length {c} has {3 * n} enriched dofs")
    a = (3 * strip.enriched[:n, None] + np.arange(3)).ravel()
    out = np.concatenate([u_orig, np.zeros(3 * n)])
    b = (3 * strip.copies[c][:, None] + np.arange(3)).ravel() if n else np.zeros(0, np.int64)
    out[b] = u_orig[a] + d
    return out
