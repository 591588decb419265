"""POD with a polynomial regression of the reduced coordinates, a reduced-order model of its own
package that tissuebench finds by its entry point (group ``tissuebench.methods``)."""
from .method import PodPolyReg

__all__ = ["PodPolyReg"]
__version__ = "0.1.0"
