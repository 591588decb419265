"""Weighted skinning + cubature ROM (wsc-skinning-cubature: Hou, Xiong, Xia 2023).

Modules: :mod:`.handles` (furthest-point sampling), :mod:`.weights` (normalised RBF
skinning weights, boundary handles), :mod:`.subspace` (affine subspace ``u = U q``,
Dirichlet part), :mod:`.biharmonic` (biharmonic coordinates of sample elements, libigl),
:mod:`.cubature` (full, the paper's BGBC and our RBF rules), :mod:`.nnls`
(optimised rule), :mod:`.reduced` (cubature energy, force, tangent), :mod:`.loads`
(reduced loads), :mod:`.stepper` (implicit reduced dynamics), :mod:`.method` (the
registered ``"wsc"`` method and its online model).
"""
from .cubature import Cubature, bgbc_cubature, full_cubature, rbf_cubature
from .handles import furthest_point_sampling, resolve_count
from .method import CUBATURES, Wsc, WscModel
from .subspace import MassProjector, Subspace
from .weights import shepard_kernel, skinning_weights

__all__ = ["Cubature", "bgbc_cubature", "full_cubature", "rbf_cubature", "furthest_point_sampling", "resolve_count",
           "CUBATURES", "Wsc", "WscModel", "MassProjector", "Subspace", "shepard_kernel", "skinning_weights"]
