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

from dataclasses import dataclass

import numpy as np

from ..base import check_parameters

__all__ = ["Contact", "locate"]


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


def _integer(v, who, key):
    if float(v) != int(v):
        raise ValueError(f"{who}.step: mu[{key!r}] = {v!r} must be an integer (a node index)")
    return int(v)


def locate(vademecum, mu, who: str, need_S: bool):
    """(Contact or None, status, message, lam) for ``mu``; None with status ``"failed"``."""
    fam = vademecum.family
    keys = ("node",) if "node" in mu and "position" not in mu else ("position",)
    mu = check_parameters(mu, keys, who)
    lam = float(check_parameters(mu, ("load_factor",), who)["load_factor"]) if "load_factor" in mu else 1.0
    if fam.kind == "line":
        s = float(mu["position"])
        try:
            rows, vals = fam.load_at(s)
        except ValueError as exc:
            return None, "failed", f"{who}: {exc}", lam
        pw = vademecum.parameter_weights(s)
        if pw is None:
            lo, hi = fam.coords[0], fam.coords[-1]
            msg = f"{who}: s = {s:g} outside the vademecum's parameter range [{lo:g}, {hi:g}]"
            return (None, "failed", msg + " (S(s) undefined)", lam) if need_S else \
                (Contact(-1, s, rows, vals, None, "extrapolation", msg), "extrapolation", msg, lam)
        return Contact(int(pw[0][0]), s, rows, vals, pw[1] @ vademecum.S[pw[0]]), "ok", "", lam
    if keys == ("position",):
        j = _integer(mu["position"], who, "position")
        if not 0 <= j < fam.n_parameters:
            return None, "failed", (f"{who}: position {j} outside the accessible nodes 0..{fam.n_parameters - 1}"), lam
        node = int(fam.nodes[j])
    else:
        node = _integer(mu["node"], who, "node")
        if not 0 <= node < fam.ndof // 3:
            return None, "failed", f"{who}: node {node} is not a node of the mesh (0..{fam.ndof // 3 - 1})", lam
        j = fam.parameter_of_node(node)
        if j < 0:
            msg = f"{who}: node {node} is not on the accessible surface (the vademecum's domain)"
            if need_S:
                return None, "failed", msg + " (S undefined there)", lam
            rows, vals = fam.load_at(node)
            return Contact(-1, node, rows, vals, None, "extrapolation", msg), "extrapolation", msg, lam
    rows, vals = fam.load_at(node)
    return Contact(j, node, rows, vals, vademecum.S[j]), "ok", "", lam
