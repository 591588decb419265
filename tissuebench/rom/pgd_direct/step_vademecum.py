"""The computational vademecum of one time step and its fast evaluation.

``z(x, p_1, ..., p_P) = sum_i F_i(x) prod_d G_{i,d}(p_d)`` (paper eq. 6 with the load
dimension): ``F_i`` stacks the computed state fields at ``t + dt`` on the free dofs,
``G_{i,d}`` are nodal values on the uniform mesh of parameter ``d`` (the previous
state's reduced coordinates, then the load factor). Evaluation interpolates every
``G_{., d}`` at ``p_d`` (P1; linear extrapolation beyond an end, flagged) and multiplies:
``weights_i = prod_d G_{i,d}(p_d)`` — P x N operations, independent of the mesh size.

Stored as NPZ (arrays) plus a JSON string of the metadata; no pickle.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .meshes import ParameterMesh

__all__ = ["Evaluator", "StepVademecum"]


@dataclass
class StepVademecum:
    """Separated solution of one step of ``scheme`` with step ``dt``.

    Attributes
    ----------
    scheme : str
    dt : float
        Time step [s] the vademecum integrates.
    options : dict
        Scheme options (HHT: alpha).
    param_names : list of str
        ``"u:0" .. "u:m-1", "v:0" ...``, then ``"load_factor"``.
    meshes : list of ParameterMesh
        One per parameter, all with the same number of nodes.
    space : dict
        Output field -> (n_free, N) spatial modes (unit of the field).
    factors : (P, n_nodes, N) array
        Parametric modes at the mesh nodes.
    stats : dict
        Offline record (PGD solves, modes, fixed-point iterations, times).
    """

    scheme: str
    dt: float
    options: dict
    param_names: list
    meshes: list
    space: dict
    factors: np.ndarray
    stats: dict = field(default_factory=dict)

    @property
    def n_modes(self) -> int:
        """Separated terms evaluated online (PGD modes of every solve plus input terms)."""
        return self.factors.shape[2]

    @property
    def n_params(self) -> int:
        return len(self.meshes)

    @property
    def domains(self) -> dict:
        return {name: (m.lo, m.hi) for name, m in zip(self.param_names, self.meshes)}

    def weights(self, params) -> np.ndarray:
        """``prod_d G_{i,d}(p_d)`` for every term, shape (N,)."""
        return Evaluator(self).weights(np.asarray(params, dtype=float))[0]

    def evaluate(self, params) -> dict:
        """The computed fields at ``params`` (P,): {field: (n_free,)} (full size; offline checks)."""
        w = self.weights(params)
        return {k: F @ w for k, F in self.space.items()}

    # ------------------------------------------------------------------ storage
    def save(self, path) -> Path:
        """Write ``path`` (.npz): arrays plus the metadata as a JSON string."""
        path = Path(path)
        meta = {"scheme": self.scheme, "dt": self.dt, "options": self.options, "param_names": self.param_names,
                "meshes": [[m.lo, m.hi, m.n_nodes] for m in self.meshes], "fields": list(self.space),
                "stats": self.stats}
        arrays = {f"space_{k}": v for k, v in self.space.items()}
        np.savez(path, factors=self.factors, meta=np.array(json.dumps(meta, default=float)), **arrays)
        return path

    @classmethod
    def load(cls, path) -> StepVademecum:
        with np.load(Path(path), allow_pickle=False) as data:
            meta = json.loads(str(data["meta"]))
            space = {k: data[f"space_{k}"] for k in meta["fields"]}
            factors = data["factors"]
        meshes = [ParameterMesh(float(lo), float(hi), int(n)) for lo, hi, n in meta["meshes"]]
        return cls(meta["scheme"], float(meta["dt"]), meta["options"], meta["param_names"], meshes, space,
                   factors, meta["stats"])


class Evaluator:
    """Precomputed arrays for the online evaluation of a :class:`StepVademecum`.

    ``weights(p)`` costs a handful of NumPy calls on (P, N) arrays, into buffers kept between
    calls: locate each ``p_d`` on its uniform mesh, gather the left nodal values and the
    element differences of every parameter in one ``take`` (they are stored side by side),
    interpolate, multiply over the parameters.
    """

    def __init__(self, vad: StepVademecum):
        G = np.ascontiguousarray(vad.factors)
        P, n, N = G.shape
        self.left = np.ascontiguousarray(G[:, :-1, :])
        self.diff = np.ascontiguousarray(G[:, 1:, :] - G[:, :-1, :])
        # row (d, k) of the table: [left value | difference] of parameter d's element k
        self._table = np.ascontiguousarray(np.concatenate([self.left, self.diff], axis=2).reshape(P * (n - 1), 2 * N))
        self._base = np.arange(P) * (n - 1)
        self.lo = np.array([m.lo for m in vad.meshes])
        self.inv_h = np.array([1.0 / m.h for m in vad.meshes])
        self.last = vad.factors.shape[1] - 2
        self.rows = np.arange(vad.n_params)
        self.tol = 1e-12 * (self.last + 1)
        self.N = N
        self._s, self._k = np.empty(P), np.empty(P)
        self._ki = np.empty(P, dtype=np.int64)
        self._g = np.empty((P, 2 * N))

    def positions(self, p: np.ndarray) -> np.ndarray:
        """``s`` (P,): each parameter's position in element units (a buffer, overwritten by the next call)."""
        s = np.subtract(p, self.lo, out=self._s)
        s *= self.inv_h
        return s

    def blend(self, s) -> np.ndarray:
        """``weights`` (N,), a new array, at finite positions ``s``."""
        # clip before the cast: truncation is the floor for s >= 0, and s < 0 maps to element 0
        k = np.clip(s, 0.0, self.last, out=self._k)
        ki = self._ki
        ki[:] = k
        w = np.subtract(s, ki, out=self._k)[:, None]
        ki += self._base
        g = self._table.take(ki, axis=0, out=self._g)
        vals, dv = g[:, :self.N], g[:, self.N:]
        dv *= w
        vals += dv
        with np.errstate(over="ignore", invalid="ignore"):  # far extrapolation: reported by the caller
            return vals.prod(axis=0)

    def weights(self, p: np.ndarray):
        """(weights (N,), s (P,)): ``s`` is the position in element units (outside ``[0, n-1]``: extrapolated)."""
        s = self.positions(p)
        return self.blend(s), s.copy()

    def inside(self, s) -> bool:
        """Every parameter within its interval (the haptic path: two reductions)."""
        return bool(s.min() >= -self.tol and s.max() <= self.last + 1 + self.tol)

    def outside(self, s) -> np.ndarray:
        """Indices of the parameters outside their interval."""
        return np.flatnonzero((s < -self.tol) | (s > self.last + 1 + self.tol))
