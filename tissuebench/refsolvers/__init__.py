"""Full-order finite-element references: meshes, materials, backends, Newton-Raphson."""
from .materials import (MATERIALS, Guccione, LinearElastic, Material, MooneyRivlin, NeoHookean,
                        NeoHookeanDecoupled, SaintVenantKirchhoff, make_material)
from .mesh import Mesh, node_layout
from .problem import BodyForce, Dirichlet, FollowerPressure, PointLoad, Problem, SurfaceTraction
from .backends import BACKENDS, Backend, make_backend

__all__ = ["MATERIALS", "Guccione", "LinearElastic", "Material", "MooneyRivlin", "NeoHookean",
           "NeoHookeanDecoupled", "SaintVenantKirchhoff", "make_material", "Mesh", "node_layout", "BodyForce",
           "Dirichlet",
           "FollowerPressure", "PointLoad", "Problem", "SurfaceTraction", "BACKENDS", "Backend",
           "make_backend"]
