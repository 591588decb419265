"""Online side shared by the PGD models: the contact position and its status.

The parameter of a step is the load position (``mu`` keys):

* 1D family: ``"position"`` = the coordinate s. Off the mesh: the step fails (no load
  can be placed). Outside the vademecum's s-range but on the mesh: srb still projects
  the load (status ``"extrapolation"``), prb and the vademecum evaluation need S(s) and
  fail.
* surface family: ``"position"`` = index in the list of accessible nodes
  (:attr:`PointLoadFamily.nodes`, 0 .. n_s - 1; an integer value, else ValueError;
  out of range: the step fails), or ``"node"`` = a mesh node id: an accessible node is
  the same as its index; another node of the mesh is outside the vademecum's domain
  (srb: ``"extrapolation"``; prb: fails); a node id not in the mesh fails.

``"load_factor"`` (optional, default 1) scales the contact force linearly.
"""
from __future__ import annotations

import bisect
from dataclasses import dataclass

import numpy as np

from ..online import parameter

__all__ = ["Contact", "locate", "LocatedContact"]


@dataclass
class Contact:
    """A resolved contact: parameter-node index (or -1 off the domain), mesh position
    (line: s; surface: node id), the load on the free dofs, S(s_p) (None off the domain)."""

    index: int
    where: float
    rows: np.ndarray
    values: np.ndarray
    S_p: np.ndarray | None
    status: str = "ok"
    message: str = ""
    block: slice | None = None  # ``rows`` as a slice when they are consecutive (a view of the basis rows)


def _integer(v, who, key):
    if float(v) != int(v):
        raise ValueError(f"{who}.step: mu[{key!r}] = {v!r} must be an integer (a node index)")
    return int(v)


class _Tables:
    """What :func:`locate` looks up at every step, prepared once per vademecum: the line mesh
    and the parameter coordinates as Python lists (bisection without NumPy), the free-dof
    rows and values of the load at every parameter node of a surface family."""

    def __init__(self, vademecum):
        fam = vademecum.family
        self.line = fam.kind == "line"
        if self.line:
            self.x = [float(v) for v in fam.x]
            x0, x1 = self.x[0], self.x[-1]
            self.x_lo, self.x_hi = x0 - 1e-12 * abs(x1 - x0), x1 + 1e-12 * abs(x1 - x0)
            self.s = [float(v) for v in fam.coords]
            s0, s1 = self.s[0], self.s[-1]
            self.s_lo, self.s_hi = s0 - 1e-12 * (s1 - s0), s1 + 1e-12 * (s1 - s0)
            self.free = fam.free_index.tolist()
            self.force = float(fam.force)
        else:
            self.node_loads = {}  # node -> (rows, values) of the load on that node


def _tables(vademecum) -> _Tables:
    t = vademecum.__dict__.get("_locate_tables")
    if t is None:
        t = vademecum.__dict__["_locate_tables"] = _Tables(vademecum)
    return t


def _line_load(t: _Tables, s: float):
    """(rows, values) of the P1-distributed source at ``s`` on the line mesh, fixed dofs and
    zero values dropped (:meth:`~.family.PointLoadFamily.load_at`, its arithmetic)."""
    x = t.x
    k = min(max(bisect.bisect_left(x, s) - 1, 0), len(x) - 2)
    u = (s - x[k]) / (x[k + 1] - x[k])
    r0, r1 = t.free[k], t.free[k + 1]
    v0, v1 = -t.force * (1.0 - u), -t.force * u
    if r0 >= 0 and r1 == r0 + 1 and v0 != 0.0 and v1 != 0.0:  # the common case: two free neighbours
        return np.array((r0, r1)), np.array((v0, v1)), slice(r0, r1 + 1)
    rows, vals = [], []
    for r, v in ((r0, v0), (r1, v1)):
        if r >= 0 and v != 0.0:
            rows.append(r)
            vals.append(v)
    return np.array(rows, dtype=np.int64), np.array(vals), None


class LocatedContact:
    """Mixin of the online models whose step places the contact with :func:`locate`: the step reads
    ``position`` (and ``node`` on a surface, which the ``contact_nodes`` hook declares)."""

    def step_parameters(self) -> tuple:
        return ("position",) + super().step_parameters()


def locate(vademecum, mu, who: str, need_S: bool):
    """(Contact or None, status, message, lam) for ``mu``; None with status ``"failed"``."""
    fam = vademecum.family
    t = _tables(vademecum)
    lam = parameter(mu, "load_factor", who) if "load_factor" in mu else 1.0
    if t.line:
        s = parameter(mu, "position", who)
        if not t.x_lo <= s <= t.x_hi:
            x = fam.x
            return None, "failed", f"{who}: position s = {s!r} is off the mesh [{x[0]:g}, {x[-1]:g}]", lam
        rows, vals, block = _line_load(t, s)
        if not t.s_lo <= s <= t.s_hi:
            lo, hi = fam.coords[0], fam.coords[-1]
            msg = f"{who}: s = {s:g} outside the vademecum's parameter range [{lo:g}, {hi:g}]"
            return (None, "failed", msg + " (S(s) undefined)", lam) if need_S else \
                (Contact(-1, s, rows, vals, None, "extrapolation", msg), "extrapolation", msg, lam)
        c = t.s
        k = min(max(bisect.bisect_left(c, s) - 1, 0), len(c) - 2)
        u = (s - c[k]) / (c[k + 1] - c[k])
        S = vademecum.S
        S_p = np.dot(np.array((1.0 - u, u)), S[k:k + 2]) if need_S else None
        return Contact(k, s, rows, vals, S_p, block=block), "ok", "", lam
    if "node" in mu and "position" not in mu:
        node = _integer(parameter(mu, "node", who), who, "node")
        if not 0 <= node < fam.ndof // 3:
            return None, "failed", f"{who}: node {node} is not a node of the mesh (0..{fam.ndof // 3 - 1})", lam
        j = fam.parameter_of_node(node)
        if j < 0:
            msg = f"{who}: node {node} is not on the accessible surface (the vademecum's domain)"
            if need_S:
                return None, "failed", msg + " (S undefined there)", lam
            rows, vals = fam.load_at(node)
            return Contact(-1, node, rows, vals, None, "extrapolation", msg), "extrapolation", msg, lam
    else:
        j = _integer(parameter(mu, "position", who), who, "position")
        if not 0 <= j < fam.n_parameters:
            return None, "failed", (f"{who}: position {j} outside the accessible nodes 0..{fam.n_parameters - 1}"), lam
        node = int(fam.nodes[j])
    load = t.node_loads.get(node)
    if load is None:
        load = t.node_loads[node] = fam.load_at(node)
    return Contact(j, node, load[0], load[1], vademecum.S[j]), "ok", "", lam
