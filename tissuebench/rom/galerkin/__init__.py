"""POD-Galerkin for nonlinear structural dynamics, with ECSW or DEIM hyper-reduction (``"pod_galerkin"``).

One module per concern: :mod:`.basis` (the POD of the trajectory snapshots), :mod:`.kernel`
(element quantities fast enough for a haptic step), :mod:`.forces` (the reduced force, tangent and
energy of weighted elements), :mod:`.ecsw` and :mod:`.deim` (the hyper-reductions),
:mod:`.system` (the reduced system the integrators march), :mod:`.model` (the online model) and
:mod:`.method` (the registered method).
"""
from .method import HYPER, PodGalerkin
from .model import GalerkinModel
from .system import ReducedSystem, reduced_system

__all__ = ["PodGalerkin", "GalerkinModel", "ReducedSystem", "reduced_system", "HYPER"]
