"""Figures of the studies (matplotlib, Agg): written next to their tables."""
from __future__ import annotations

from pathlib import Path

__all__ = ["plot_anm_pod"]


from .figures import pyplot as _plt


def _fig9(curves, case, modes, path):
    """Load factor vs max displacement: the reference and ANM-POD orders (paper Fig. 9)."""
    plt = _plt()
    c = curves[(curves["case"] == case) & (curves["modes"] == modes)]
    fig, ax = plt.subplots(figsize=(7, 5))
    ref = c.drop_duplicates("load_factor")
    ax.plot(ref["ref_max_displacement"], ref["load_factor"], "k-", lw=2.5, label="Newton-Raphson")
    for order, g in c.groupby("order"):
        ax.plot(g["rom_max_displacement"], g["load_factor"], ".--", label=f"order {order}")
    ax.set_xlabel("max displacement")
    ax.set_ylabel("load factor")
    ax.set_title(f"{case}: ANM-POD, {modes} modes (one series from the origin)")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _pareto(table, case, path):
    """Error vs online latency for every configuration, the Pareto front highlighted."""
    plt = _plt()
    t = table[table["case"] == case].sort_values("step_median_s")
    err = t["max_rel_l2"].clip(lower=1e-16)
    front = err.cummin() == err
    fig, ax = plt.subplots(figsize=(7, 5))
    sc = ax.scatter(t["step_median_s"] * 1e6, err, c=t["order"], s=12 + 6 * t["modes"], cmap="viridis")
    ax.plot(t["step_median_s"][front] * 1e6, err[front], "r-", label="Pareto front")
    ax.axhline(0.01, color="grey", ls=":", label="1 %")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("online step, median [us]")
    ax.set_ylabel("max relative l2 error over the load path")
    fig.colorbar(sc, label="order (marker size: modes)")
    ax.set_title(f"{case}: error vs latency (reference step {t['reference_step_s'].iloc[0] * 1e3:.1f} ms)")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3, which="both")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _interp(interp, path):
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7, 5))
    for (case, method, align), g in interp.groupby(["case", "method", "align"]):
        ax.plot(g["distance"], g["rom_error"], "o", label=f"{case}: {method} {align}".strip())
    ax.set_yscale("log")
    ax.set_xlabel("distance to the nearest stored load position")
    ax.set_ylabel("ANM-POD error at the held-out position (max over the load path)")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3, which="both")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_anm_pod(table, curves, interp, folder: Path):
    """fig9_<case>.png, pareto_<case>.png and interpolation.png into ``folder``."""
    folder = Path(folder)
    for case in table["case"].unique():
        t = table[table["case"] == case]
        modes = int(t["modes"].max())
        _fig9(curves, case, modes, folder / f"fig9_{case}.png")
        _pareto(table, case, folder / f"pareto_{case}.png")
    if len(interp):
        _interp(interp, folder / "interpolation.png")
