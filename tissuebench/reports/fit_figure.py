"""The learning curves of a fit (``OUT/learning_curves.png``): error against references added, per family.

:func:`draw_learning_curves` is the ``figures`` callable :func:`~tissuebench.studies.fit.run_fit`
takes (the studies layer computes and records the curves in the fit's manifest, this layer
draws them: studies never imports reports). One line per family that learns from references:
its lead unit's headline error after each round, against the references the fit added to its
training; a hollow marker where the model grew (``n_modes`` ...) instead, labelled with what grew,
and a grey one for the growth measured in the same round and not kept; the requirement's error
as a dashed line, a cross where a unit failed (its error is infinite: drawn at the top).
"""
from __future__ import annotations

import math
from pathlib import Path

from matplotlib.ticker import MaxNLocator

from ..studies.atomic_files import replacing
from .figures import pyplot

__all__ = ["draw_learning_curves"]


def _grew_text(p: dict) -> str:
    """What grew at a growth point: ``n_modes 45``, ``ecsw_tol 0.0025``."""
    key = p.get("grew")
    value = (p.get("refined") or {}).get(key, p.get("size"))
    return f"{key} {value:g}" if isinstance(value, (int, float)) else str(key)


def draw_learning_curves(manifest: dict, path) -> Path:
    """Draw the learning curves of a fit's ``manifest`` into the PNG ``path`` (atomically)."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7.0, 4.2))
    finite = [p["error"] for st in manifest["families"].values() for p in st["curve"]
              if p["error"] is not None and math.isfinite(p["error"]) and p["error"] > 0]
    top = max(finite) * 2 if finite else 1.0
    for name, st in manifest["families"].items():
        curve = [p for p in st["curve"] if not p.get("dropped")]
        if not curve or not st.get("learns", True):
            continue
        x = [p["references"] for p in curve]
        y = [p["error"] if p["error"] is not None and math.isfinite(p["error"]) else top for p in curve]
        line, = ax.plot(x, y, marker="o", label=name)
        grown = [(a, b) for a, b, p in zip(x, y, curve) if p["action"] == "grow"]
        if grown:
            ax.plot(*zip(*grown), linestyle="none", marker="o", markersize=11, markerfacecolor="none",
                    color=line.get_color())
        for a, b, p in zip(x, y, curve):
            if p["action"] == "grow" and p.get("grew"):
                ax.annotate(_grew_text(p), (a, b), textcoords="offset points", xytext=(8, -3), fontsize=7,
                            color=line.get_color())
        tried = [p for p in st["curve"] if p.get("dropped") and p["action"] == "grow" and p["error"] is not None
                 and math.isfinite(p["error"])]
        if tried:  # the growth not kept: measured in the same round, less accurate or too slow
            ax.plot([p["references"] for p in tried], [p["error"] for p in tried], linestyle="none", marker="o",
                    markersize=6, markerfacecolor="none", color="0.6")
            for p in tried:
                ax.annotate(_grew_text(p), (p["references"], p["error"]), textcoords="offset points",
                            xytext=(-8, -3), ha="right", fontsize=7, color="0.5")
        failed = [(a, b) for a, b, p in zip(x, y, curve) if p["status"] != "ok"]
        if failed:
            ax.plot(*zip(*failed), linestyle="none", marker="x", color=line.get_color())
    error = next((c for c in _clauses(manifest) if c[0] == "error"), None)
    if error is not None:
        ax.axhline(error[2], color="k", linestyle="--", linewidth=1, label=f"required {100 * error[2]:.3g} %")
    ax.set_yscale("log")
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))  # references are counted
    ax.set_xlabel("references added by the fit")
    ax.set_ylabel(f"headline error ({manifest.get('error_metric', 'error')})")
    ax.set_title(f"tissuebench fit: {manifest.get('scene_name', '')} (hollow: the model grew; grey: the growth "
                 "not kept)", fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    path = Path(path)
    with replacing(path, "--out", suffix=".png") as png:
        fig.savefig(png, dpi=110)
    plt.close(fig)
    return path


def _clauses(manifest: dict) -> list:
    return [tuple(c) for c in manifest.get("target", [])]
