"""The finite-element model as pyMOR operators (imported when a ``pymor_galerkin`` model is built).

* :class:`InternalForce`: ``u_free -> f_int(u)[free]`` with ``u`` the free values and the prescribed
  ones at the step's load factor (a parameter ``load_factor`` where a support moves), ``apply`` and
  ``jacobian`` from the backend (full assembly), ``restricted(dofs)`` from the elements around
  ``dofs`` (:func:`tissuebench.rom.element_kernel`): what pyMOR's
  ``EmpiricalInterpolatedOperator`` evaluates online.
* :class:`FirstOrderForm`: ``M x' + A(x) = F`` of ``M_r q'' + C_r q' + f_r(q) = lam f_r1`` with
  ``x = [q, v]``, ``A(x) = [-v, f_r(q) + C_r v]``, for pyMOR's time steppers (first-order systems).
  pyMOR's ``BlockOperator`` evaluates the Jacobian of its block ``(i, j)`` at ``U.blocks[i]``, not at
  the block ``j`` it acts on, so a nonlinear off-diagonal block (``f_r`` acts on ``q``, sits in the row
  of ``v``) would be linearised at ``v``: this operator composes the blocks itself.
"""
from __future__ import annotations

import numpy as np
from pymor.operators.interface import Operator
from pymor.operators.numpy import NumpyMatrixOperator
from pymor.vectorarrays.numpy import NumpyVectorSpace
from tissuebench.rom import element_kernel

__all__ = ["InternalForce", "RestrictedForce", "FirstOrderForm", "load_factor_of"]


def load_factor_of(mu) -> float:
    return float(mu["load_factor"][0]) if mu is not None and "load_factor" in mu else 1.0


class _Lift:
    """The full displacement of free values and the prescribed values at a load factor."""

    def __init__(self, training):
        be = training.backend
        self.problem, self.ndof = be.problem, be.ndof
        self.free = np.asarray(training.free_dofs)
        self.fixed = np.asarray(self.problem.fixed_dofs)
        self.moving = bool(len(self.fixed)) and any(np.any(self.problem.prescribed_values(lam) != 0.0)
                                                    for lam in (0.5, 1.0))

    def prescribed(self, lam):
        return self.problem.prescribed_values(lam) if self.moving else None

    def full(self, u_free, lam):
        u = np.zeros(self.ndof)
        u[self.free] = u_free
        if self.moving:
            u[self.fixed] = self.problem.prescribed_values(lam)
        return u


class InternalForce(Operator):
    """``f_int`` on the free dofs of a training's backend (module docstring)."""

    linear = False

    def __init__(self, training, name="internal_force"):
        self.training, self.backend = training, training.backend
        self.lift = _Lift(training)
        self.source = self.range = NumpyVectorSpace(len(self.lift.free))
        self.parameters_own = {"load_factor": 1} if self.lift.moving else {}
        self.name = name

    def apply(self, U, mu=None):
        assert U in self.source
        lam, free = load_factor_of(mu), self.lift.free
        out = [self.backend.internal_force(self.lift.full(u, lam))[free] for u in U.to_numpy().T]
        return self.range.make_array(np.array(out).T.reshape(len(free), len(U)))

    def jacobian(self, U, mu=None):
        assert len(U) == 1
        free = self.lift.free
        K = self.backend.tangent(self.lift.full(U.to_numpy()[:, 0], load_factor_of(mu)))
        return NumpyMatrixOperator(K[free][:, free].tocsc(), name=f"{self.name}_jacobian")

    def restricted(self, dofs):
        op = RestrictedForce(self.training, self.lift, np.asarray(dofs, dtype=np.int64), self.parameters_own)
        return op, op.source_dofs


class RestrictedForce(Operator):
    """The internal force at free dofs ``dofs`` from the free values of the elements around them."""

    linear = False

    def __init__(self, training, lift, dofs, params):
        # pyMOR reads every constructor argument back as an attribute (its parameters)
        self.training, self.lift, self.dofs, self.params = training, lift, dofs, dict(params)
        free, fixed = lift.free, lift.fixed
        targets = free[dofs]  # global dofs of the interpolation points
        element_dofs = training.backend.element_dofs()
        cells = np.flatnonzero(np.isin(element_dofs, targets).any(axis=1))
        self.kernel = element_kernel(training, cells)
        self.dofs_loc = self.kernel.dofs  # (m, n_loc) global dofs
        position = np.full(lift.ndof, -1, dtype=np.int64)
        position[free] = np.arange(len(free))
        loc_free = position[self.dofs_loc]  # free index of each local dof, -1 on the fixed ones
        src = np.unique(loc_free[loc_free >= 0])
        self.source_dofs = src
        src_of = np.full(len(free), -1, dtype=np.int64)
        src_of[src] = np.arange(len(src))
        self._src_loc = np.where(loc_free >= 0, src_of[np.maximum(loc_free, 0)], -1)  # (m, n_loc) source index
        self._free_mask = self._src_loc >= 0
        fixed_pos = np.full(lift.ndof, -1, dtype=np.int64)
        fixed_pos[fixed] = np.arange(len(fixed))
        self._fixed_loc = fixed_pos[self.dofs_loc]  # index into the prescribed values, -1 elsewhere
        row_of = np.full(lift.ndof, -1, dtype=np.int64)
        row_of[targets] = np.arange(len(targets))
        rows = row_of[self.dofs_loc]  # (m, n_loc): the interpolation row of each local dof, -1 elsewhere
        self._e, self._a = np.nonzero(rows >= 0)
        self._rows = rows[self._e, self._a]
        self.n_rows, self.n_src = len(targets), len(src)
        self.source = NumpyVectorSpace(len(src))
        self.range = NumpyVectorSpace(len(targets))
        self.parameters_own = params
        self.name = "internal_force_restricted"

    def _local(self, u_src, lam):
        u_loc = np.zeros(self.dofs_loc.shape)
        u_loc[self._free_mask] = u_src[self._src_loc[self._free_mask]]
        values = self.lift.prescribed(lam)
        if values is not None:
            on_fixed = self._fixed_loc >= 0
            u_loc[on_fixed] = values[self._fixed_loc[on_fixed]]
        return u_loc

    def apply(self, U, mu=None):
        lam = load_factor_of(mu)
        out = np.zeros((self.n_rows, len(U)))
        for j, u in enumerate(U.to_numpy().T):
            fe = self.kernel.forces(self._local(u, lam))
            out[:, j] = np.bincount(self._rows, weights=fe[self._e, self._a], minlength=self.n_rows)
        return self.range.make_array(out)

    def jacobian(self, U, mu=None):
        assert len(U) == 1
        _, K = self.kernel.forces_and_tangents(self._local(U.to_numpy()[:, 0], load_factor_of(mu)))
        Krows = K[self._e, self._a]  # (k, n_loc): the rows of the interpolation dofs
        cols = self._src_loc[self._e]  # (k, n_loc)
        keep = cols >= 0
        flat = (np.repeat(self._rows[:, None], cols.shape[1], axis=1)[keep] * self.n_src + cols[keep])
        J = np.bincount(flat, weights=Krows[keep], minlength=self.n_rows * self.n_src).reshape(self.n_rows,
                                                                                              self.n_src)
        return NumpyMatrixOperator(J, name=f"{self.name}_jacobian")


class FirstOrderForm(Operator):
    """``A([q, v]) = [-v, f_r(q) + C_r v]`` on ``NumpyVectorSpace(2 r)`` (module docstring)."""

    linear = False

    def __init__(self, force, damping):
        self.force, self.damping = force, np.asarray(damping, float)
        self.C = self.damping
        self.r = force.source.dim
        self.source = self.range = NumpyVectorSpace(2 * self.r)
        self.parameters_own = dict(force.parameters)
        self.name = "first_order_form"

    def apply(self, U, mu=None):
        X = U.to_numpy()
        q, v = X[:self.r], X[self.r:]
        f = self.force.apply(self.force.source.make_array(q), mu=mu).to_numpy()
        return self.range.make_array(np.vstack([-v, f + self.C @ v]))

    def jacobian(self, U, mu=None):
        assert len(U) == 1
        r = self.r
        q = self.force.source.make_array(U.to_numpy()[:r])
        K = self.force.jacobian(q, mu=mu)
        if isinstance(K, NumpyMatrixOperator):
            K = K.matrix
        else:  # a generic linear operator: its matrix by columns
            K = K.apply(self.force.source.make_array(np.eye(r))).to_numpy()
        K = K.toarray() if hasattr(K, "toarray") else np.asarray(K)
        J = np.block([[np.zeros((r, r)), -np.eye(r)], [K, self.C]])
        return NumpyMatrixOperator(J, name=f"{self.name}_jacobian")
