"""Separated functions of space and the step parameters: the algebra of one step in PGD form.

A :class:`SepField` is ``u(x, p_1, ..., p_P) = sum_t X_t(x) prod_d G_{d,t}(p_d)`` stored
as nodal values: ``space`` (n, T) holds the spatial vectors (free dofs of a state field,
or a stack of fields), ``factors[d]`` (n_nodes_d, T) the nodal values of the 1D
functions on the mesh of parameter ``d``. The parameters are the reduced coordinates of
the previous state and the load factor of the step (:mod:`.offline` fixes their order).

Linear operations (sums, scalar multiples, a matrix applied to the spatial factors)
only concatenate or transform terms, so the one-step formulas of :mod:`.schemes` run
unchanged on SepFields and on plain vectors. The PGD solver (:mod:`tissuebench.rom.separated`)
consumes :meth:`SepField.weak_terms` and returns modes that :meth:`SepField.from_modes`
turns back into a SepField.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["SepField", "coordinate_field", "parameter_field", "stack_fields"]


@dataclass
class SepField:
    """Separated function with ``T`` terms (see the module docstring).

    Attributes
    ----------
    space : (n, T) array
        Spatial factors.
    factors : list of (n_nodes_d, T) arrays
        Parametric factors, one array per parameter dimension.
    """

    space: np.ndarray
    factors: list

    def __post_init__(self):
        self.space = np.asarray(self.space, dtype=float).reshape(len(self.space), -1)
        T = self.space.shape[1]
        self.factors = [np.asarray(g, dtype=float).reshape(len(g), -1) for g in self.factors]
        for d, g in enumerate(self.factors):
            if g.shape[1] != T:
                raise ValueError(f"SepField: factors[{d}] has {g.shape[1]} terms, space has {T}")

    @property
    def n_terms(self) -> int:
        return self.space.shape[1]

    @property
    def n_space(self) -> int:
        return self.space.shape[0]

    @property
    def n_params(self) -> int:
        return len(self.factors)

    # ------------------------------------------------------------------ algebra
    def _check_like(self, other):
        if not isinstance(other, SepField):
            return NotImplemented
        if other.n_space != self.n_space or [len(g) for g in other.factors] != [len(g) for g in self.factors]:
            raise ValueError("SepField: operands live on different spaces or parameter meshes")
        return other

    def __add__(self, other):
        if self._check_like(other) is NotImplemented:
            return NotImplemented
        return SepField(np.hstack([self.space, other.space]),
                        [np.hstack([a, b]) for a, b in zip(self.factors, other.factors)])

    def __mul__(self, c):
        if not np.isscalar(c):
            return NotImplemented
        return SepField(float(c) * self.space, [g.copy() for g in self.factors])

    __rmul__ = __mul__

    def __neg__(self):
        return -1.0 * self

    def __sub__(self, other):
        return self + (-1.0 * other)

    def __truediv__(self, c):
        return self * (1.0 / float(c))

    def apply(self, A) -> SepField:
        """``A`` (sparse or dense (n', n)) applied to every spatial factor."""
        return SepField(np.asarray(A @ self.space).reshape(-1, self.n_terms), [g.copy() for g in self.factors])

    # ------------------------------------------------------------------ evaluation
    def parameter_weights(self, meshes, params) -> np.ndarray:
        """``prod_d G_{d,t}(p_d)`` for every term, shape (T,), by P1 interpolation on ``meshes``."""
        params = np.asarray(params, dtype=float).ravel()
        if len(params) != self.n_params or len(meshes) != self.n_params:
            raise ValueError(f"SepField: {self.n_params} parameters expected, got {len(params)} values "
                             f"and {len(meshes)} meshes")
        w = np.ones(self.n_terms)
        for mesh, g, p in zip(meshes, self.factors, params):
            w *= mesh.interpolate(g, p)
        return w

    def evaluate(self, meshes, params) -> np.ndarray:
        """The field at parameter values ``params`` (P,), shape (n,)."""
        return self.space @ self.parameter_weights(meshes, params)

    # ------------------------------------------------------------------ PGD interface
    def weak_terms(self, space_operator=None, parameter_masses=None) -> list:
        """Terms ``(B X_t, W_1 G_1t, ..., W_P G_Pt)`` of the weak right-hand side.

        ``space_operator`` B (default identity) and the parameter mass matrices W_d
        (default identity) turn nodal values into the load vector of a Galerkin problem.
        """
        X = self.space if space_operator is None else np.asarray(space_operator @ self.space)
        Gs = self.factors if parameter_masses is None else [W @ g for W, g in zip(parameter_masses, self.factors)]
        return [(X[:, t],) + tuple(g[:, t] for g in Gs) for t in range(self.n_terms)]

    @classmethod
    def from_modes(cls, modes) -> SepField:
        """SepField of PGD modes ``[(X_i, G_1i, ..., G_Pi), ...]`` (amplitudes folded in)."""
        if not modes:
            raise ValueError("SepField.from_modes: no modes")
        D = len(modes[0])
        cols = [np.column_stack([np.asarray(m[d], dtype=float) for m in modes]) for d in range(D)]
        return cls(cols[0], cols[1:])

    @classmethod
    def zeros(cls, n_space: int, meshes) -> SepField:
        return cls(np.zeros((n_space, 0)), [np.zeros((m.n_nodes, 0)) for m in meshes])

    def combined(self) -> SepField:
        """The same function with terms of identical parametric factors merged (zero terms dropped).

        The one-step formulas repeat the input fields many times (u0 enters a Bathe step
        five times); merging keeps the PGD right-hand sides short.
        """
        groups: dict = {}
        for t in range(self.n_terms):
            key = b"".join(g[:, t].tobytes() for g in self.factors)
            groups.setdefault(key, []).append(t)
        cols = [idx for idx in groups.values()]
        X = np.column_stack([self.space[:, idx].sum(axis=1) for idx in cols]) if cols else self.space[:, :0]
        keep = np.linalg.norm(X, axis=0) > 0.0
        first = [idx[0] for idx, k in zip(cols, keep) if k]
        return SepField(X[:, keep], [g[:, first] for g in self.factors])

    def leading(self, n: int) -> SepField:
        """The first ``n`` terms (greedy PGD modes are nested)."""
        return SepField(self.space[:, :n], [g[:, :n] for g in self.factors])


def parameter_field(vector, dim: int, meshes, power: int = 1) -> SepField:
    """``vector(x) * p_dim**power``: one term, the parameter's nodal values in ``dim``, ones elsewhere."""
    factors = [np.ones((m.n_nodes, 1)) for m in meshes]
    factors[dim] = (meshes[dim].nodes ** power)[:, None]
    return SepField(np.asarray(vector, dtype=float).reshape(-1, 1), factors)


def coordinate_field(basis, dims, meshes) -> SepField:
    """``sum_j basis[:, j] p_{dims[j]}``: a state field in reduced coordinates (one term per mode)."""
    basis = np.asarray(basis, dtype=float)
    if basis.ndim != 2 or basis.shape[1] != len(dims):
        raise ValueError(f"coordinate_field: basis shape {basis.shape} for {len(dims)} dimensions")
    factors = [np.ones((m.n_nodes, len(dims))) for m in meshes]
    for j, d in enumerate(dims):
        factors[d][:, j] = meshes[d].nodes
    return SepField(basis, factors)


def stack_fields(fields) -> SepField:
    """Block stack ``[f_1; f_2; ...]`` in space (each term lives in its own block)."""
    fields = list(fields)
    n = [f.n_space for f in fields]
    offsets = np.concatenate([[0], np.cumsum(n)])
    blocks = []
    for k, f in enumerate(fields):
        X = np.zeros((offsets[-1], f.n_terms))
        X[offsets[k]:offsets[k + 1]] = f.space
        blocks.append(X)
    return SepField(np.hstack(blocks), [np.hstack([f.factors[d] for f in fields])
                                        for d in range(fields[0].n_params)])
