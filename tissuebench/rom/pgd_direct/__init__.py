"""PGD-POD direct time integrator (pgd-pod-direct-integration): method ``"pgd_direct"``.

Modules: :mod:`.meshes` (parameter intervals and 1D meshes), :mod:`.fields` (separated
functions), :mod:`.schemes` (the inner integrators, on vectors and separated fields),
:mod:`.operators` (system and POD bases from a Training), :mod:`.balance` (the
coordinates the PGD sees), :mod:`.nonlinear` (separated SVK force), :mod:`.offline` (the
PGD solves of one step), :mod:`.step_vademecum` (storage and evaluation), :mod:`.model`
(online), :mod:`.method` (the registered method). Trajectory trainings of catalogue scenes: ``studies.trajectories``.
"""
from .meshes import ParameterMesh, parameter_domain
from .method import DirectIntegrator
from .model import DirectModel
from .schemes import SCHEMES, StepOperators, VectorAlgebra
from .step_vademecum import StepVademecum

__all__ = [
           "SCHEMES",
           "DirectIntegrator",
           "DirectModel",
           "ParameterMesh",
           "StepOperators",
           "StepVademecum",
           "VectorAlgebra",
           "parameter_domain",
]
