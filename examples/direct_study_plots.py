"""Figures of ``direct_study.py``: the paper's Figs. 2, 5, 15-17 and 20 redrawn with our runs.

Each function takes what the study collected and writes one PNG (Agg backend). The
paper's own curves are not digitised: each figure's title states what the paper shows
(its caption and reported numbers) so the two can be read side by side.
"""
from __future__ import annotations

import numpy as np

from tissuebench.reports.figures import pyplot

__all__ = ["beam", "curves", "frame", "liver", "long_run", "wave"]


def _save(fig, path):
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    pyplot().close(fig)
    return path


def frame(c, path):
    """Fig. 2: slab displacements, analytical vs the direct integrator (8 PGD modes)."""
    plt = pyplot()
    fig, axes = plt.subplots(2, 1, figsize=(8, 5.5), sharex=True)
    for j, ax in enumerate(axes):
        ax.plot(c["t"], c["analytical"][:, j], "k-", lw=2.5, alpha=0.4, label="analytical")
        for key, style in (("central_difference", "C0--"), ("forward_euler", "C3:")):
            u = c[key][:, j]
            ax.plot(c["t"][:len(u)], u, style, label=f"PGD-POD, {key.replace('_', ' ')}")
        ax.set_ylabel(f"u{j + 1} [m]")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    axes[-1].set_xlabel("t [s]")
    fig.suptitle("frame_2dof, step load 1e4 N (paper Fig. 2: PGD, 8 modes, 'almost indistinguishable')",
                 fontsize=9)
    return _save(fig, path)


def beam(curves, rows, path):
    """Fig. 5: midpoint deflection for each dt and scheme (1 POD mode, the paper's one-dof beam);
    relative RMSE versus dt for each scheme, load sampling and number of modes."""
    plt = pyplot()
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2))
    t, w = curves["reference"]
    for ax, integ in zip(axes[:2], ("central_difference", "bathe")):
        ax.plot(t, w, "k-", lw=2.5, alpha=0.4, label="full Bathe, dt=1e-4")
        for (name, m, dt), (tt, ww) in ((k, v) for k, v in curves.items() if isinstance(k, tuple)):
            if name == integ and m == 1 and np.all(np.isfinite(ww)) and np.max(np.abs(ww)) < 3 * np.max(np.abs(w)):
                ax.plot(tt, ww, ".-", ms=3, lw=0.8, label=f"dt={dt:g}")
        ax.set_title(f"inside the step: {integ.replace('_', ' ')} (1 POD mode)", fontsize=9)
        ax.set_xlabel("t [s]")
        ax.set_ylabel("midpoint w [m]")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=6)
    ax = axes[2]
    styles = {("forward_euler", "end", 1): "v-", ("central_difference", "end", 1): "o-",
              ("bathe", "end", 1): "s-", ("bathe", "end", 4): "s--", ("bathe", "mid", 4): "D--"}
    for k, (key, mk) in enumerate(styles.items()):
        rr = [r for r in rows if (r["integrator"], r.get("load_at"), r.get("pod_modes")) == key and "error" not in r]
        err = [r["rmse_vs_reference"] if r["stable"] else np.nan for r in rr]
        ax.loglog([r["dt"] for r in rr], err, mk, label=f"{key[0].replace('_', ' ')}, load {key[1]}, {key[2]} mode(s)")
        bad = [r["dt"] for r in rr if not r["stable"]]
        if bad:
            ax.text(0.25, 0.55 - 0.06 * k, f"{key[0].replace('_', ' ')} ({key[2]}): unstable at dt >= {min(bad):g}",
                    transform=ax.transAxes, fontsize=6)
    ax.axvspan(0.005, 0.05, color="0.9", zorder=0)
    ax.set_xlabel("dt [s] (shaded: the paper's range)")
    ax.set_ylabel("relative RMSE of w(t)")
    ax.set_title("paper Figs. 5-6: explicit sensitive to dt, Bathe more accurate", fontsize=9)
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=6)
    return _save(fig, path)


def wave(figs, path):
    """Figs. 15-16: mid and top u_z, HHT reference vs 3 and 8 POD modes (central difference = paper's FE)."""
    plt = pyplot()
    fig, axes = plt.subplots(2, 2, figsize=(13, 7), sharex=True)
    for col, variant in enumerate(("linear", "svk")):
        t = figs[(variant, "t")]
        for row, name in enumerate(("mid_uz", "top_uz")):
            ax = axes[row, col]
            ax.plot(t[1:], figs[(variant, "reference")][name], "k-", lw=2.5, alpha=0.4, label="HHT -0.05 (ref.)")
            for m, style in ((3, "C1--"), (8, "C0-")):
                y = figs[(variant, "central_difference", m)][name]
                ax.plot(t[1:len(y) + 1], y, style, lw=1, label=f"PGD-POD {m} modes (central diff.)")
            ax.set_ylabel(f"{name} [m]")
            ax.grid(alpha=0.3)
            ax.set_title(f"wave_block {variant}", fontsize=9)
        axes[1, col].set_xlabel("t [s]")
    axes[0, 0].legend(fontsize=7)
    fig.suptitle("paper Figs. 15-16 (3 and 8 modes, forward Euler = our central difference) and 18 (SVK)",
                 fontsize=9)
    return _save(fig, path)


def _modes_panel(ax, mr):
    """Error versus POD modes for each velocity basis, the projection floor and the 1 % target."""
    for vb, style in (("velocity", "o-"), ("displacement", "s-")):
        rr = [r for r in mr if r.get("velocity_basis", "velocity") == vb]
        if rr:
            ax.semilogy([r["pod_modes"] for r in rr], [r["rmse_vs_reference"] for r in rr], style,
                        label=f"direct (HHT inside), velocity basis: {vb}")
    rr = [r for r in mr if r.get("velocity_basis", "velocity") == "velocity"]
    ax.semilogy([r["pod_modes"] for r in rr], [r["projection_floor"] for r in rr], "k--",
                label="projection of the ref. (floor)")
    ax.axhline(0.01, color="r", lw=0.8, label="target 1 %")
    ax.set_xlabel("POD modes per field")
    ax.set_ylabel("relative displacement RMSE vs HHT ref.")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=7)


def curves(rows, path):
    """Error versus POD modes (with the projection floor) and versus parameter-mesh nodes."""
    plt = pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    _modes_panel(axes[0], [r for r in rows if r["curve"] == "modes"])
    nr = [r for r in rows if r["curve"] == "nodes"]
    n = [r["n_nodes"] for r in nr]
    axes[1].loglog(n, [r["rmse_vs_full_same_integrator"] for r in nr], "o-",
                   label="trajectory vs full central diff. (SVK, 4 kPa)")
    axes[1].loglog(n, [r["rmse_vs_reference"] for r in nr], "s-", label="trajectory vs HHT ref. (SVK, 4 kPa)")
    sr = [r for r in rows if r["curve"] == "step_nodes"]
    if sr:
        h = np.array([r["n_nodes"] for r in sr], float)
        e = np.array([r["step_map_l2_error"] for r in sr])
        axes[1].loglog(h, e, "D-", label="one step, SVK x300 amplitudes (L2 over the box)")
        axes[1].loglog(h, e[0] * ((h[0] - 1) / (h - 1)) ** 2, "k:", lw=0.8, label="slope -2")
    axes[1].set_xlabel("nodes per parameter mesh")
    for ax in axes:
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=7)
    fig.suptitle("wave_block: why the error stops at the POD floor (modes) and how the mesh enters (SVK)",
                 fontsize=9)
    return _save(fig, path)


def long_run(hist, path):
    """Fig. 17: top u_z over the long run and the relative energy error of each scheme."""
    plt = pyplot()
    fig, axes = plt.subplots(2, 1, figsize=(11, 6.5), sharex=True)
    y_max = np.nanmax(np.abs(hist["reference"][1]))
    for name, (t, y, e) in hist.items():
        ok = np.isfinite(y) & (np.abs(y) < 3 * y_max)  # a blow-up is cut at 3 x the reference amplitude
        axes[0].plot(t[:len(y)][ok], y[ok], lw=0.8 if name != "reference" else 2.0,
                     alpha=1.0 if name != "reference" else 0.4, label=name)
        ok_e = np.isfinite(e) & (np.abs(e) < 10)
        axes[1].plot(t[:len(e)][ok_e], e[ok_e], lw=0.8, label=name)
    axes[0].set_ylabel("top u_z [m]")
    axes[0].set_ylim(-1.6 * y_max, 0.6 * y_max)
    axes[1].set_ylabel("(KE + SE - W - E0) / max energy")
    axes[1].set_xlabel("t [s]")
    for ax in axes:
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    fig.suptitle("paper Fig. 17: 8 modes, Bathe inside the step, stable over 10 s (energy shown below)",
                 fontsize=9)
    return _save(fig, path)


def liver(hist, rows, path):
    """Fig. 20: tool-tip displacement (reference vs 1, 3, 7 modes), error history, spectra, modes curve."""
    plt = pyplot()
    fig, axes = plt.subplots(1, 4, figsize=(20, 4.2))
    t, y_ref = hist["t"], hist["reference"]
    axes[0].plot(t, y_ref, "k-", lw=2.5, alpha=0.4, label="HHT (ref.)")
    for m, c in ((1, "C0"), (3, "C1"), (7, "C2")):
        for vb, ls in (("velocity", "-"), ("displacement", "--")):
            y = hist.get(("hht", m, vb))
            if y is None:
                continue
            axes[0].plot(t[:len(y)], y, c + ls, lw=0.9, label=f"{m} modes, v basis: {vb}")
            axes[1].plot(t[:len(y)], np.abs(y - y_ref[:len(y)]) / np.max(np.abs(y_ref)), c + ls, lw=0.9,
                         label=f"{m} modes, {vb}")
    free = t >= 0.5
    dt = t[1] - t[0]
    for key, style in (("reference", "k-"), (("hht", 1, "displacement"), "C0-"), (("hht", 3, "displacement"), "C1-"),
                       (("hht", 7, "displacement"), "C2-")):
        y = hist.get(key)
        if y is None or len(y) < len(t):
            continue
        x = y[free] - y[free].mean()
        amp = np.abs(np.fft.rfft(x * np.hanning(len(x))))
        label = "reference" if key == "reference" else f"{key[1]} modes"
        axes[2].semilogy(np.fft.rfftfreq(len(x), dt), amp + 1e-30, style, lw=0.9, label=label)
    _modes_panel(axes[3], [r for r in rows if r.get("curve") == "modes"])
    axes[0].set_ylabel("tool tip u_y [m]")
    axes[1].set_ylabel("|error| / max |ref|")
    axes[2].set_xlim(0, 100)
    axes[2].set_xlabel("frequency [Hz] (free vibration, t >= 0.5 s; HHT inside)")
    for ax in axes[:2]:
        ax.set_xlabel("t [s]")
    for ax in axes[:3]:
        ax.grid(alpha=0.3)
        ax.legend(fontsize=6)
    fig.suptitle("paper Fig. 20: 1, 3, 7 modes converge to the FE reference; fewer modes lose the high frequencies",
                 fontsize=9)
    return _save(fig, path)
