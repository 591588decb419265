"""PGD vademecums (pgd-vademecum-cutting): offline separated representation of the
response to a moving point load, online srb / prb projections, the SVK Ritz model and
cracking-node cutting. Importing the package registers the methods ``pgd`` (and the
others as they are added) in :data:`tissuebench.rom.METHODS`."""
from .family import PointLoadFamily, anterior_nodes, line_family, nodal_areas, surface_family
from .linear import Pgd, PgdModel
from .cutting_method import CuttingModel, PgdCutting
from .svk import PgdSvk, PgdSvkModel
from .projections import PrbProjection, SrbProjection, make_projection
from .training import family_from_training, pgd_training
from .vademecum import Vademecum, build_vademecum

__all__ = ["PointLoadFamily", "anterior_nodes", "line_family", "nodal_areas", "surface_family", "Pgd", "PgdModel",
           "CuttingModel", "PgdCutting", "PgdSvk", "PgdSvkModel",
           "PrbProjection", "SrbProjection", "make_projection", "family_from_training", "pgd_training", "Vademecum",
           "build_vademecum"]
