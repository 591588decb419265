"""Matplotlib figures of reference runs (Agg, written to files)."""
from __future__ import annotations

from pathlib import Path

from ..reference.result import TABLE_COLUMNS

__all__ = ["pyplot", "plot_monitors", "plot_line_state", "TABLE_COLUMNS"]


def pyplot():
    """``matplotlib.pyplot`` on the file-only Agg backend (no display needed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_monitors(result, path: Path) -> Path:
    """Each monitored quantity of a :class:`ReferenceResult` against its load factor or time."""
    plt = pyplot()
    t = result.table
    x = "load_factor" if "load_factor" in t else "time"
    cols = [c for c in t.columns if c not in TABLE_COLUMNS]
    fig, axes = plt.subplots(len(cols) or 1, 1, figsize=(7, 2.4 * max(len(cols), 1)), squeeze=False)
    ok = t["converged"].to_numpy(bool)
    for ax, c in zip(axes[:, 0], cols):
        ax.plot(t[x][ok], t[c][ok], ".-")
        ax.set_ylabel(c)
        ax.grid(alpha=0.3)
    axes[-1, 0].set_xlabel(x)
    fig.suptitle(f"{result.case} ({result.backend}, {result.resolution}): {result.status}")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)


def plot_line_state(result, path: Path) -> Path:
    """The final state of a 1D model: each component along x."""
    plt = pyplot()
    x, U = result.points[:, 0], result.final_displacement
    fig, ax = plt.subplots(figsize=(7, 3.5))
    for i, c in enumerate(result.components):
        ax.plot(x, U[:, i], "o-", label=c)
    ax.set_xlabel("x")
    ax.legend()
    ax.grid(alpha=0.3)
    ax.set_title(f"{result.case}: final state ({result.status})")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)
