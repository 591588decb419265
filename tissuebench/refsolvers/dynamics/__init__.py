"""Full-order time integrators for ``M a + C v + f_int(u) = f_ext(t, u)``.

HHT-alpha, Newmark (trapezoidal), Bathe composite, backward Euler, explicit central
difference and forward Euler, with per-step energy bookkeeping; prescribed motions of the
fixed dofs (non-homogeneous Dirichlet conditions) in every scheme. Integrators consume a
:class:`SecondOrderSystem`, never a backend module.
"""
from .base import Integrator, StepReport, check_dt
from .driver import integrate
from .explicit import CentralDifference, ForwardEuler, critical_time_step, lumped_mass, max_frequency
from .implicit import HHT, BackwardEuler, Bathe, Newmark, NewmarkFamily
from .step_newton import NewtonOptions
from .registry import INTEGRATORS, make_integrator
from .result import DynamicsResult
from .system import SecondOrderSystem

__all__ = ["Integrator", "StepReport", "check_dt", "integrate", "CentralDifference", "ForwardEuler",
           "critical_time_step", "lumped_mass", "max_frequency", "HHT", "BackwardEuler", "Bathe", "Newmark",
           "NewmarkFamily", "NewtonOptions", "INTEGRATORS", "make_integrator", "DynamicsResult",
           "SecondOrderSystem"]
