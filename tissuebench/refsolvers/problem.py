"""Backend-neutral description of a solid-mechanics problem.

A :class:`Problem` bundles a :class:`~tissuebench.refsolvers.mesh.Mesh`, an element
(``"P1"``, ``"P2"``, ``"Q1"``), a material, Dirichlet sets and loads. Everything that
depends on a load factor ``lam`` scales linearly with it: prescribed displacements,
point loads, tractions, follower pressure and body force.

Node selections (``nodes`` of :class:`Dirichlet` and :class:`PointLoad`) are either an
integer array of discretisation-node indices (see :func:`~tissuebench.refsolvers.mesh.node_layout`)
or a predicate ``where(x) -> bool mask`` evaluated on the node coordinates ``x`` of
shape ``(n_nodes, 3)``. Facet selections are ``(n_facets, 3|4)`` vertex arrays with
outward orientation (see :meth:`Mesh.select_facets`) or a predicate on vertices.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Callable, Sequence

import numpy as np

from .materials import Material
from .mesh import ELEMENTS, Mesh, node_layout
from .rigid_modes import check_rigid_body_modes


def _finite_array(name, value, shape=None):
    arr = np.asarray(value, dtype=float)
    if shape is not None and arr.shape != shape:
        raise ValueError(f"{name} must have shape {shape}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} contains a non-finite value: {arr[~np.isfinite(arr)][0]!r}")
    return arr


def _resolve_nodes(name, nodes, coords):
    if callable(nodes):
        mask = np.asarray(nodes(coords), dtype=bool)
        if mask.shape != (len(coords),):
            raise ValueError(f"{name}: predicate must return a mask of shape ({len(coords)},), got {mask.shape}")
        idx = np.flatnonzero(mask)
    else:
        idx = np.unique(np.asarray(nodes, dtype=np.int64).ravel())
        if idx.size and (idx.min() < 0 or idx.max() >= len(coords)):
            raise ValueError(f"{name}: node index out of range 0..{len(coords) - 1}")
    if idx.size == 0:
        raise ValueError(f"{name}: the node selection is empty")
    return idx


@dataclass(frozen=True)
class Dirichlet:
    """Prescribed displacement components on a node set.

    ``value`` is the displacement at load factor 1: a scalar or ``(len(components),)``
    array applied to every node, or a callable ``value(x) -> (n, len(components))``.
    With ``scaled=False`` the value is imposed at every load factor.

    ``motion``, when given, replaces ``value`` for motions that are not linear in the
    load factor (a rigid rotation): ``motion(x, load_factor) -> (n, len(components))``
    displacement of the reference positions ``x`` (n, 3), zero at load factor 0. Newton's
    step cutting then follows the motion itself instead of its chord.
    """

    nodes: np.ndarray | Callable
    components: Sequence[int] = (0, 1, 2)
    value: float | np.ndarray | Callable = 0.0
    scaled: bool = True
    motion: Callable | None = None

    def __post_init__(self):
        comps = tuple(int(c) for c in self.components)
        if not comps or any(c not in (0, 1, 2) for c in comps) or len(set(comps)) != len(comps):
            raise ValueError(f"Dirichlet.components must be distinct values in (0, 1, 2), got {self.components!r}")
        object.__setattr__(self, "components", comps)
        if not callable(self.value):
            _finite_array("Dirichlet.value", self.value)
        if self.motion is not None and not callable(self.motion):
            raise TypeError(f"Dirichlet.motion must be callable (x, load_factor), got {type(self.motion).__name__}")

    def motion_values(self, coords, idx, load_factor: float) -> np.ndarray:
        """Displacements (flattened like :meth:`resolve`) of the motion at ``load_factor``."""
        vals = self.motion(coords[idx], float(load_factor))
        return _finite_array("Dirichlet.motion(x, load_factor)", vals, (len(idx), len(self.components))).ravel()

    def resolve(self, coords):
        """Return (dofs, values at load factor 1, scaled flags) for node coordinates ``coords``."""
        idx = _resolve_nodes("Dirichlet.nodes", self.nodes, coords)
        comps = np.array(self.components)
        if self.motion is not None:
            vals = self.motion_values(coords, idx, 1.0).reshape(len(idx), len(comps))
        elif callable(self.value):
            vals = _finite_array("Dirichlet.value(x)", self.value(coords[idx]), (len(idx), len(comps)))
        else:
            vals = np.broadcast_to(_finite_array("Dirichlet.value", self.value), (len(idx), len(comps)))
        dofs = (3 * idx[:, None] + comps[None, :]).ravel()
        return dofs, np.asarray(vals, float).ravel(), np.full(dofs.size, self.scaled)


@dataclass(frozen=True)
class PointLoad:
    """Nodal forces: ``force`` of shape (3,) on every selected node, or (n_selected, 3)."""

    nodes: np.ndarray | Callable
    force: np.ndarray

    def __post_init__(self):
        _finite_array("PointLoad.force", self.force)

    def resolve(self, coords):
        idx = _resolve_nodes("PointLoad.nodes", self.nodes, coords)
        f = np.asarray(self.force, float)
        if f.shape not in ((3,), (len(idx), 3)):
            raise ValueError(f"PointLoad.force must have shape (3,) or ({len(idx)}, 3), got {f.shape}")
        return idx, np.broadcast_to(f, (len(idx), 3))


@dataclass(frozen=True)
class SurfaceTraction:
    """Dead traction per reference area, shape (3,), on boundary facets."""

    facets: np.ndarray | Callable
    traction: np.ndarray

    def __post_init__(self):
        _finite_array("SurfaceTraction.traction", self.traction, (3,))


@dataclass(frozen=True)
class FollowerPressure:
    """Pressure on the deformed surface, acting against the outward normal: t = -p n da."""

    facets: np.ndarray | Callable
    pressure: float

    def __post_init__(self):
        _finite_array("FollowerPressure.pressure", self.pressure, ())


@dataclass(frozen=True)
class BodyForce:
    """Body force per reference volume, shape (3,)."""

    force: np.ndarray

    def __post_init__(self):
        _finite_array("BodyForce.force", self.force, (3,))


@dataclass(frozen=True, eq=False)
class Problem:
    """Mesh + element + material + boundary conditions + loads (+ density for dynamics).

    Raises
    ------
    ValueError
        Unknown element, material data inconsistent with the mesh, no Dirichlet set
        (rigid-body modes left free), a Dirichlet set that cannot remove all six
        rigid-body modes of every connected body of the mesh (see
        :mod:`~tissuebench.refsolvers.rigid_modes`; :mod:`~tissuebench.refsolvers.well_posed`
        has the check a scene makes of its loads,
        :func:`~tissuebench.refsolvers.well_posed.check_loads_do_work`).
    """

    mesh: Mesh
    material: Material
    element: str = "P1"
    dirichlet: Sequence[Dirichlet] = ()
    loads: Sequence[PointLoad | SurfaceTraction | FollowerPressure | BodyForce] = ()
    density: float = 1.0
    quadrature_order: int | None = None

    def __post_init__(self):
        if not isinstance(self.mesh, Mesh):
            raise TypeError(f"mesh must be a tissuebench Mesh, got {type(self.mesh).__name__}")
        if not isinstance(self.material, Material):
            raise TypeError(f"material must be a tissuebench Material, got {type(self.material).__name__}")
        if self.element not in ELEMENTS:
            raise ValueError(f"element={self.element!r} is not one of {sorted(ELEMENTS)}")
        node_layout(self.mesh, self.element)  # checks element/cell compatibility
        self.material.validate_for_mesh(self.mesh.n_cells)
        if not (np.isfinite(self.density) and self.density > 0):
            raise ValueError(f"density must be a finite number > 0, got {self.density!r}")
        if self.quadrature_order is not None and int(self.quadrature_order) < 1:
            raise ValueError(f"quadrature_order must be >= 1, got {self.quadrature_order!r}")
        object.__setattr__(self, "dirichlet", tuple(self.dirichlet))
        object.__setattr__(self, "loads", tuple(self.loads))
        for ld in self.loads:
            if not isinstance(ld, (PointLoad, SurfaceTraction, FollowerPressure, BodyForce)):
                raise TypeError(f"loads: unsupported load type {type(ld).__name__}")
        if not self.dirichlet:
            raise ValueError("dirichlet: no Dirichlet condition given; the six rigid-body modes are free")
        check_rigid_body_modes(self)

    # ---------------------------------------------------------------- layout
    @cached_property
    def layout(self):
        """(nodes, cell_nodes) of the discretisation, see :func:`node_layout`."""
        return node_layout(self.mesh, self.element)

    @property
    def nodes(self) -> np.ndarray:
        return self.layout[0]

    @property
    def ndof(self) -> int:
        return 3 * len(self.nodes)

    @cached_property
    def constraints(self):
        """(dofs, values at load factor 1, scaled) of all Dirichlet sets, dofs unique."""
        return self._constraint_table[:3]

    @cached_property
    def _constraint_table(self):
        parts = [d.resolve(self.nodes) for d in self.dirichlet]
        dofs = np.concatenate([p[0] for p in parts])
        vals = np.concatenate([p[1] for p in parts])
        scaled = np.concatenate([p[2] for p in parts])
        owner = np.concatenate([np.full(len(p[0]), k) for k, p in enumerate(parts)])
        self._check_overlaps(dofs, owner)
        # sets that share dofs prescribe the same values there (checked): the later one is kept
        _, first_rev = np.unique(dofs[::-1], return_index=True)
        keep = len(dofs) - 1 - first_rev
        # motions are re-evaluated per load factor on the dofs they still own
        motions = []
        for k, d in enumerate(self.dirichlet):
            if d.motion is None:
                continue
            idx = _resolve_nodes("Dirichlet.nodes", d.nodes, self.nodes)
            all_dofs = (3 * idx[:, None] + np.array(d.components)[None, :]).ravel()
            pos = np.searchsorted(dofs[keep], all_dofs)
            won = owner[keep][pos] == k
            motions.append((d, idx, won, pos[won]))
        return dofs[keep], vals[keep], scaled[keep], motions

    @property
    def fixed_dofs(self) -> np.ndarray:
        return self.constraints[0]

    @cached_property
    def free_dofs(self) -> np.ndarray:
        return np.setdiff1d(np.arange(self.ndof), self.fixed_dofs)

    def prescribed_values(self, load_factor: float) -> np.ndarray:
        """Values of the fixed dofs at ``load_factor``, aligned with :attr:`fixed_dofs`."""
        _, vals, scaled, motions = self._constraint_table
        out = np.where(scaled, load_factor * vals, vals)
        for d, idx, won, pos in motions:
            out[pos] = d.motion_values(self.nodes, idx, load_factor)[won]
        return out

    def support_reactions(self, f_int, f_ext) -> np.ndarray:
        """The nodal forces the supports exert on the body, shape (ndof,): ``f_int - f_ext`` on the
        fixed dofs (the external load lumped onto a supported node included: the support carries
        it), zero on the free ones. In static equilibrium they balance the applied load: their sum
        plus the sum of ``f_ext`` is zero."""
        r = np.zeros(self.ndof)
        fixed = self.fixed_dofs
        r[fixed] = np.asarray(f_int, float)[fixed] - np.asarray(f_ext, float)[fixed]
        return r

    def point_load_vector(self) -> np.ndarray:
        """Nodal point loads at load factor 1, shape (ndof,)."""
        f = np.zeros(self.ndof)
        for ld in self.loads:
            if isinstance(ld, PointLoad):
                idx, force = ld.resolve(self.nodes)
                np.add.at(f.reshape(-1, 3), idx, force)
        return f

    def facets_of(self, load) -> np.ndarray:
        """Outward-oriented vertex arrays of the facets a traction/pressure acts on."""
        if callable(load.facets):
            facets = self.mesh.select_facets(load.facets)
        else:
            facets = np.asarray(load.facets, dtype=np.int64)
        name = type(load).__name__
        if facets.ndim != 2 or len(facets) == 0:
            raise ValueError(f"{name}.facets: empty or malformed facet selection (shape {facets.shape})")
        return facets

    def _dirichlet_values(self, k: int, load_factor: float) -> np.ndarray:
        """The values Dirichlet set ``k`` prescribes on its dofs (in :meth:`Dirichlet.resolve`
        order) at ``load_factor``."""
        d = self.dirichlet[k]
        if d.motion is not None:
            idx = _resolve_nodes("Dirichlet.nodes", d.nodes, self.nodes)
            return d.motion_values(self.nodes, idx, load_factor)
        _, vals, scaled = d.resolve(self.nodes)
        return np.where(scaled, load_factor * vals, vals)

    def _check_overlaps(self, dofs: np.ndarray, owner: np.ndarray) -> None:
        """Refuse two Dirichlet sets prescribing different values on a shared dof (at load
        factors 0.5 and 1: a clamp and a motion, or +d and -d), naming both sets."""
        order = np.argsort(dofs, kind="stable")
        sd, so = dofs[order], owner[order]
        shared = np.flatnonzero((sd[1:] == sd[:-1]) & (so[1:] != so[:-1]))
        if not len(shared):
            return
        pos = {k: {int(dof): i for i, dof in enumerate(dofs[owner == k])} for k in np.unique(owner)}
        for lf in (1.0, 0.5):
            values = {k: self._dirichlet_values(int(k), lf) for k in pos}
            scale = max(float(np.max(np.abs(v), initial=0.0)) for v in values.values()) or 1.0
            for i in shared:
                dof, a, b = int(sd[i]), int(so[i]), int(so[i + 1])
                va, vb = values[a][pos[a][dof]], values[b][pos[b][dof]]
                if abs(va - vb) > 1e-9 * scale:
                    n_shared = len(np.intersect1d(dofs[owner == a], dofs[owner == b]))
                    raise ValueError(f"dirichlet[{a}] and dirichlet[{b}] prescribe different values on the dofs they "
                                     f"share ({n_shared} dofs; e.g. node {dof // 3} component {'xyz'[dof % 3]}: "
                                     f"{va:.6g} vs {vb:.6g} at load factor {lf:g}); give each dof one value")
