"""A displacement backend that corrects another one's volumetric energy (the contract shared by
:class:`~tissuebench.refsolvers.anp.AnpBackend` and
:class:`~tissuebench.refsolvers.mean_dilatation.MeanDilatationBackend`).

The corrected backend wraps the plain backend of the same problem (P1, Q1) and adds a correction
to its internal force, tangent and energy; the external loads, the mass, the element Jacobians
and the linear solvers are the plain backend's, delegated here once.
"""
from __future__ import annotations

from .backends.base import Backend, make_backend


class CorrectedBackend(Backend):
    """The plain backend ``base`` of ``problem`` with the operators that are not corrected delegated.

    Parameters
    ----------
    problem : Problem
    backend : {"skfem", "ngsolve"} or Backend
        The plain backend of ``problem`` (reused when given).
    why_not : str
        Why the correction does not apply to ``problem`` (empty: it applies); a ValueError if not empty.
    formulation : str
        The formulation's name (``Backend.formulation``).
    """

    def __init__(self, problem, backend, why_not: str, formulation: str):
        if why_not:
            raise ValueError(why_not)
        self.base = backend if isinstance(backend, Backend) and backend.problem is problem \
            else make_backend(backend, problem)
        super().__init__(problem)
        self.name, self.formulation = self.base.name, formulation

    def external_force(self, u, load_factor):
        return self.base.external_force(u, load_factor)

    def external_tangent(self, u, load_factor):
        return self.base.external_tangent(u, load_factor)

    def mass(self, lumped=False):
        return self.base.mass(lumped)

    def min_jacobian(self, u):
        return self.base.min_jacobian(u)

    def make_linear_solver(self, name="auto", **options):
        return self.base.make_linear_solver(name, **options)
