"""The scene a :class:`~.base.Training` refers to, for the methods that need the scene itself
(the PGD vademecums, the practitioner baselines): ``Training.scene`` when the harness passed it,
else the catalogue case ``info["case"]`` loaded with its variant and resolution and checked
against ``info["scene_hash"]``, so a case entry whose parameters or mesh differ from the
catalogue's is never silently replaced by the catalogue's default."""
from __future__ import annotations

from ..cases import load
from .base import Training

__all__ = ["scene_of"]


def scene_of(training: Training, who: str, required: bool = False):
    """The scene of ``training`` (module docstring); None when it names none, or ValueError
    naming ``who`` when ``required``, or when the loaded scene's hash differs from the recorded one."""
    if training.scene is not None:
        return training.scene
    info = training.info or {}
    if "case" not in info:
        if required:
            raise ValueError(f"{who}: the training needs its scene (Training.scene) or its name (info['case'])")
        return None
    scene = load(info["case"], resolution=info.get("resolution", "ci"), variant=info.get("variant"))
    if info.get("scene_hash") and scene.content_hash() != info["scene_hash"]:
        raise ValueError(f"{who}: the training's scene differs from the catalogue's {info['case']!r} (parameters or "
                         "mesh of the case entry); pass it as Training.scene")
    return scene
