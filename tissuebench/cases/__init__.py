"""The case catalogue: declarative scenes (``catalogue/*.toml``), their loader and mesh builders."""
from .scene import RESOLUTIONS, Scene, list_cases, load

__all__ = ["RESOLUTIONS", "Scene", "list_cases", "load"]
