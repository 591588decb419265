"""Assembly of the three 1D discrete models of the case catalogue.

A :class:`~tissuebench.cases.assembly.LineModel` (``scene.line_model()``) becomes a
:class:`LineSystem`: sparse stiffness and mass, nodal load vectors with their
histories, free and fixed dofs. Dofs are numbered node-major,
``dof = dofs_per_node * node + component``.

Models
------
``poisson1d`` (pgd-vademecum-cutting §2)
    ``k u'' = q delta(x - s)`` on the mesh interval, P1 elements, one dof ``u`` per
    node; ``K`` is the stiffness of ``-k u''`` (symmetric positive definite on the free
    dofs). Sign convention: a point load of ``value`` q at node i gives the nodal force
    ``f_i = -q``, so ``K u = f`` is the Galerkin form of ``k u'' = q delta(x - x_i)``
    and, with u(0) = u(1) = 0, reproduces ``u = (q/k) (x - s) H(x - s) - (q/k)(1 - s) x``
    (u <= 0 for q > 0). The load ``value`` of the scene is the intensity; ``q`` in
    ``[model]`` is only the default intensity of the later parametric (PGD) studies
    and is not used here. No mass (``M = M_lumped = None``).
``frame2dof`` (pgd-pod-direct-integration §4.2)
    Shear frame with rigid slabs: the node of smallest x is the ground, the others
    (by increasing x) carry ``masses`` [kg]; every cell is a storey spring of
    ``storey_stiffness`` [N/m] (12 EI / L^3, independent of the cell length). One dof
    ``u`` (lateral displacement [m]) per node; ``M = M_lumped = diag(0, m1, m2, ...)``.
``hermite_beam`` (pgd-pod-direct-integration §4.3)
    Euler-Bernoulli beam, cubic Hermite elements, dofs ``w`` [m] and ``theta = dw/dx``
    [rad] per node; ``E`` [Pa], ``A`` [m^2], ``I`` [m^4], ``rho`` [kg/m^3]. Consistent
    mass and HRZ lumped mass (diagonal of the consistent mass scaled so the
    translational entries sum to the element mass; the rotational entries,
    rho A L^3 / 78, stay positive). A point load ``value`` [N] acts on ``w``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
import scipy.sparse.linalg as spla

__all__ = ["LineSystem", "assemble_line_model", "solve_static", "frame_step_response", "MODELS"]

# model name -> component names (their order is the component index of LineModel.fixed)
MODELS = {"poisson1d": ("u",), "frame2dof": ("u",), "hermite_beam": ("w", "theta")}


@dataclass(frozen=True)
class LineSystem:
    """The assembled 1D model: ``M a + K u = sum_j f_j h_j(t)`` on the free dofs.

    Attributes
    ----------
    model : str
    K : scipy.sparse.csr_matrix, (n, n)
        Stiffness [N/m, N, N m] (poisson1d: of ``-conductivity u''``).
    M, M_lumped : scipy.sparse.csr_matrix (n, n) or None
        Consistent and diagonal lumped mass [kg, kg m^2]; None for poisson1d.
    loads : list of (f, History)
        ``f`` (n,) nodal force vector at load factor 1, ``History(t)`` its factor.
    free, fixed : (n_free,), (n_fixed,) int arrays
        Sorted dof indices; fixed dofs are held at zero.
    dofs_per_node : int
    components : tuple of str
    """

    model: str
    K: sp.csr_matrix
    M: sp.csr_matrix | None
    M_lumped: sp.csr_matrix | None
    loads: list
    free: np.ndarray
    fixed: np.ndarray
    dofs_per_node: int
    components: tuple

    @property
    def n(self) -> int:
        """Number of dofs."""
        return self.K.shape[0]

    def load_vector(self, t: float) -> np.ndarray:
        """External force (n,) at time (or pseudo-time) ``t``: ``sum_j f_j h_j(t)``."""
        out = np.zeros(self.n)
        for f, hist in self.loads:
            out += f * float(hist(t))
        return out

    def nodal(self, x) -> np.ndarray:
        """(n_nodes, dofs_per_node) view of a full dof vector ``x`` (n,)."""
        x = np.asarray(x)
        if x.shape != (self.n,):
            raise ValueError(f"x must have shape ({self.n},), got {x.shape}")
        return x.reshape(-1, self.dofs_per_node)


def _fail(field, value, why):
    raise ValueError(f"{field} = {value!r}: {why}")


def _positive(params, name):
    """params[name] as a float > 0, or ValueError naming ``model.<name>``."""
    if name not in params:
        _fail(f"model.{name}", None, "missing")
    v = params[name]
    try:
        v = float(v)
    except (TypeError, ValueError):
        _fail(f"model.{name}", v, "must be a number")
    if not (np.isfinite(v) and v > 0):
        _fail(f"model.{name}", v, "must be finite and > 0")
    return v


def _elements(mesh):
    """Cells oriented towards +x, (n_cells, 2) int, and their lengths (n_cells,) [m]."""
    x = np.asarray(mesh.x, float)
    cells = np.asarray(mesh.cells, dtype=np.int64).reshape(-1, 2)
    if cells.size and (cells.min() < 0 or cells.max() >= len(x)):
        _fail("mesh.cells", cells.max(), f"node index out of range 0..{len(x) - 1}")
    # orientation matters for the Hermite rotation: theta is dw/dx along +x
    cells = np.where((x[cells[:, 1]] < x[cells[:, 0]])[:, None], cells[:, ::-1], cells)
    h = x[cells[:, 1]] - x[cells[:, 0]]
    if np.any(h <= 0):
        i = int(np.flatnonzero(h <= 0)[0])
        _fail(f"mesh.cells[{i}]", cells[i].tolist(), "element of zero length")
    return cells, h


def _scatter(cells, blocks, dpn, n):
    """Sum element matrices ``blocks`` (n_cells, 2 dpn, 2 dpn) into a CSR (n, n)."""
    comp = np.arange(dpn)
    dofs = (dpn * cells[:, :, None] + comp).reshape(len(cells), -1)  # node-major element dofs
    rows = np.repeat(dofs, dofs.shape[1], axis=1).ravel()
    cols = np.tile(dofs, (1, dofs.shape[1])).ravel()
    return sp.csr_matrix((blocks.ravel(), (rows, cols)), shape=(n, n))


def _bar_blocks(c):
    """c (n_cells,) times [[1, -1], [-1, 1]]: P1 stiffness (k / h) or a spring (k)."""
    return c[:, None, None] * np.array([[1.0, -1.0], [-1.0, 1.0]])


def _hermite_blocks(h, EI, rhoA):
    """Euler-Bernoulli stiffness, consistent mass and HRZ lumped mass, each (n_cells, 4, 4)."""
    L = h[:, None, None]
    one = np.ones_like(L)
    Ke = EI / L**3 * np.block([[12 * one, 6 * L, -12 * one, 6 * L],
                               [6 * L, 4 * L**2, -6 * L, 2 * L**2],
                               [-12 * one, -6 * L, 12 * one, -6 * L],
                               [6 * L, 2 * L**2, -6 * L, 4 * L**2]])
    Me = rhoA * L / 420.0 * np.block([[156 * one, 22 * L, 54 * one, -13 * L],
                                      [22 * L, 4 * L**2, 13 * L, -3 * L**2],
                                      [54 * one, 13 * L, 156 * one, -22 * L],
                                      [-13 * L, -3 * L**2, -22 * L, 4 * L**2]])
    # HRZ: keep the diagonal, scaled so the translational entries carry the element mass
    d = np.diagonal(Me, axis1=1, axis2=2)
    d = d * (rhoA * h / (d[:, 0] + d[:, 2]))[:, None]
    return Ke, Me, d[:, :, None] * np.eye(4)


def _frame_masses(lm, x):
    """Nodal masses (n_nodes,) [kg]: 0 on the ground (smallest x), then ``masses`` by x."""
    masses = lm.params.get("masses")
    arr = np.asarray(masses if masses is not None else [], dtype=float).ravel()
    if arr.size != len(x) - 1:
        _fail("model.masses", masses, f"needs one mass per slab: {len(x) - 1} for a mesh of {len(x)} nodes")
    bad = ~(np.isfinite(arr) & (arr > 0))
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        _fail(f"model.masses[{i}]", float(arr[i]), "a slab mass must be finite and > 0 [kg]")
    m = np.zeros(len(x))
    m[np.argsort(x, kind="stable")[1:]] = arr
    return m


def _matrices(lm, n_nodes):
    """(K, M, M_lumped) of ``lm``; the masses are None for poisson1d."""
    cells, h = _elements(lm.mesh)
    p = lm.params
    if lm.model == "poisson1d":
        return _scatter(cells, _bar_blocks(_positive(p, "conductivity") / h), 1, n_nodes), None, None
    if lm.model == "frame2dof":
        m = _frame_masses(lm, np.asarray(lm.mesh.x, float))
        k = _positive(p, "storey_stiffness")
        K = _scatter(cells, _bar_blocks(np.full(len(h), k)), 1, n_nodes)
        # rigid slabs on massless columns: the consistent mass is already diagonal
        return K, sp.diags(m, format="csr"), sp.diags(m, format="csr")
    EI = _positive(p, "E") * _positive(p, "I")
    rhoA = _positive(p, "rho") * _positive(p, "A")
    Ke, Me, Ml = _hermite_blocks(h, EI, rhoA)
    n = 2 * n_nodes
    return _scatter(cells, Ke, 2, n), _scatter(cells, Me, 2, n), _scatter(cells, Ml, 2, n)


def _node_indices(field, idx, n_nodes):
    idx = np.asarray(idx, dtype=np.int64).ravel()
    bad = (idx < 0) | (idx >= n_nodes)
    if bad.any():
        _fail(field, int(idx[bad][0]), f"node index out of range 0..{n_nodes - 1}")
    return idx


def _fixed_dofs(lm, dpn, n_nodes):
    out = []
    for i, (idx, comp) in enumerate(lm.fixed):
        if not (isinstance(comp, (int, np.integer)) and 0 <= comp < dpn):
            _fail(f"fixed[{i}].component", comp, f"must be an index 0..{dpn - 1} of {MODELS[lm.model]}")
        out.append(dpn * _node_indices(f"fixed[{i}].nodes", idx, n_nodes) + comp)
    return np.unique(np.concatenate(out)) if out else np.zeros(0, dtype=np.int64)


def _load_vectors(lm, dpn, n_nodes):
    """[(f, History)]: the point loads on component 0 (u or w) of their nodes."""
    # poisson1d: f = -q so that K u = f solves k u'' = q delta (see the module docstring)
    sign = -1.0 if lm.model == "poisson1d" else 1.0
    out = []
    for i, (idx, value, hist) in enumerate(lm.loads):
        idx = _node_indices(f"load[{i}].nodes", idx, n_nodes)
        if not (np.ndim(value) == 0 and np.isfinite(float(value))):
            _fail(f"load[{i}].value", value, "must be one finite number per node")
        if not callable(hist):
            _fail(f"load[{i}].history", hist, "must be callable t -> load factor")
        f = np.zeros(dpn * n_nodes)
        np.add.at(f, dpn * idx, sign * float(value))
        out.append((f, hist))
    return out


def assemble_line_model(lm) -> LineSystem:
    """Assemble a :class:`~tissuebench.cases.assembly.LineModel` into a :class:`LineSystem`.

    Raises
    ------
    ValueError
        Unknown model, missing or non-positive parameter, frame masses of the wrong
        length, node or component index out of range, non-scalar load value; the
        message names the field and its value.
    """
    if lm.model not in MODELS:
        _fail("model", lm.model, f"unknown line model; valid: {sorted(MODELS)}")
    comps = MODELS[lm.model]
    dpn, n_nodes = len(comps), len(np.asarray(lm.mesh.x))
    K, M, Ml = _matrices(lm, n_nodes)
    fixed = _fixed_dofs(lm, dpn, n_nodes)
    free = np.setdiff1d(np.arange(dpn * n_nodes), fixed)
    return LineSystem(lm.model, K, M, Ml, _load_vectors(lm, dpn, n_nodes), free, fixed, dpn, comps)


def solve_static(system: LineSystem, load_factor: float = 1.0) -> np.ndarray:
    """Static solution (n,) of ``K u = load_factor * sum_j f_j`` (histories not applied).

    The free block is solved by a sparse direct solver; fixed dofs are zero. Units
    follow the model (m, rad; poisson1d: those of u).
    """
    f = float(load_factor) * sum((f for f, _ in system.loads), np.zeros(system.n))
    u = np.zeros(system.n)
    free = system.free
    Kff = sp.csc_matrix(system.K[free][:, free])
    u[free] = np.atleast_1d(spla.spsolve(Kff, f[free]))
    return u


def frame_step_response(masses, k, F, t, loaded_node) -> np.ndarray:
    """Undamped response of a shear frame from rest to a step load, by modal superposition.

    Parameters
    ----------
    masses : (n_s,) array_like
        Slab masses [kg], bottom to top.
    k : float
        Storey stiffness [N/m] (every storey, ground to first slab included).
    F : float
        Step load [N], applied from t = 0 on.
    t : (n_t,) array_like
        Times [s].
    loaded_node : int
        Loaded slab as a mesh node index: 1 first slab, ..., n_s top slab (0 is the ground).

    Returns
    -------
    (n_t, n_s) array
        Slab displacements [m]: ``u(t) = u_st - sum_j phi_j (phi_j^T M u_st) cos(w_j t)``
        with mass-normalised modes ``phi_j`` of ``K phi = w^2 M phi``.
    """
    m = np.asarray(masses, dtype=float).ravel()
    if m.size == 0 or not np.all(np.isfinite(m) & (m > 0)):
        _fail("masses", masses, "must be a non-empty list of finite masses > 0")
    if not (int(loaded_node) == loaded_node and 1 <= loaded_node <= m.size):
        _fail("loaded_node", loaded_node, f"must be a slab node 1..{m.size}")
    n = m.size
    # chain of springs: storey i joins slab i - 1 (the ground for i = 0) and slab i
    K = k * (np.diag(np.r_[2.0 * np.ones(n - 1), 1.0]) - np.eye(n, k=1) - np.eye(n, k=-1))
    f = np.zeros(n)
    f[int(loaded_node) - 1] = F
    lam, phi = sla.eigh(K, np.diag(m))
    u_st = np.linalg.solve(K, f)
    q = phi.T @ (m * u_st)
    return u_st - (np.cos(np.outer(np.asarray(t, float), np.sqrt(lam))) * q) @ phi.T
