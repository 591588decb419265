"""Human-readable views of the catalogue: ``tissuebench cases`` and ``tissuebench describe``."""
from __future__ import annotations

import pandas as pd

from ..cases.scene import RESOLUTIONS, list_cases, load
from ..reference.plan import plan_for

__all__ = ["catalogue_table", "describe", "mesh_size"]


def mesh_size(builder: str, params: dict):
    """(vertices, cells) of a structured builder from its parameters, or None when only
    meshing tells (netgen, files)."""
    if builder == "box":
        nx, ny, nz = params["divisions"]
        per_box = 6 if params.get("cell_type", "tetra") == "tetra" else 1
        return (nx + 1) * (ny + 1) * (nz + 1), per_box * nx * ny * nz
    if builder == "cornea_dome":
        c, r, n = params["core_cells"], params["ring_cells"], params["layers"]
        return (n + 1) * ((c + 1) ** 2 + 4 * c * r), n * (c * c + 4 * c * r)
    if builder in ("interval", "beam1d"):
        return params["n_elements"] + 1, params["n_elements"]
    return None


def _size(scene, resolution, build):
    params = scene.mesh_spec["resolutions"][resolution]
    size = mesh_size(scene.mesh_spec["builder"], params)
    if size is None and params == scene.mesh_spec["params"]:
        size = (scene.mesh.n_vertices, scene.mesh.n_cells)  # same mesh as the scene's resolution
    elif size is None and build:
        other = scene if scene.resolution == resolution else load(scene.path, resolution, scene.variant)
        size = (other.mesh.n_vertices, other.mesh.n_cells)
    return "-" if size is None else f"{size[0]} / {size[1]}"


def catalogue_table(build_meshes: bool = True, paper: bool = False) -> pd.DataFrame:
    """One row per case and variant: name, paper, analysis, model, vertices / cells per resolution.

    Structured meshes are counted from their parameters; netgen and file meshes are
    built for ``ci`` when ``build_meshes`` and for ``paper`` only when ``paper``.
    """
    rows = []
    for name in list_cases():
        base = load(name)
        for variant in base.variants or (None,):
            s = base if variant in (None, base.variant) else load(name, variant=variant)
            a = s.analysis
            analysis = (f"static, {a.get('load_steps', 1)} steps" if a["type"] == "static"
                        else f"dynamic {a.get('integrator', 'hht')}, dt {a['dt']:g}, T {a['t_end']:g}")
            rows.append({"case": name, "variant": variant or "", "paper": s.case.get("paper", ""), "analysis": analysis,
                         "model": s.model if not s.is_fe else f"{s.element} {s.material['name']}",
                         **{f"{r} vertices / cells": _size(s, r, build_meshes and (r == "ci" or paper))
                            for r in RESOLUTIONS}})
    return pd.DataFrame(rows)


def _fmt_region(spec) -> str:
    return ", ".join(f"{k}={v}" for k, v in spec.items())


def describe(case, resolution: str = "ci", variant: str | None = None) -> str:
    """What a reference run of ``case`` builds and why (the :class:`ModelPlan`), with the
    scene's boundary conditions, loads, monitors and the paper's numbers."""

    s = load(case, resolution=resolution, variant=variant)
    plan = plan_for(s)
    paper = f" ({s.case['paper']})" if s.case.get("paper") else ""
    where = (f"mesh: {s.mesh_label} -> " if s.mesh_spec["builder"] == "file" else
             f"mesh: builder {s.mesh_spec['builder']} {s.mesh_spec['params']} -> ")
    lines = [f"{s.name}" + (f" [{s.variant}]" if s.variant else "") + paper,
             f"  {s.case['description']}", "",
             where + f"{s.mesh.n_vertices} vertices, {s.mesh.n_cells} cells ({resolution})"]
    if s.mesh_info.get("fallback"):
        lines.append(f"  NOTE: {s.mesh_info.get('reason', 'built-in fallback shape used')}")
    if s.is_fe:
        lines.append(f"element {s.element}; material {s.material}")
    else:
        lines.append(f"model {s.model}: {s.model_params}")
    lines += [f"dirichlet: {d.get('name', '')} [{_fmt_region(d['region'])}] components {d['components']}"
              + (f" motion {d['motion']}" if "motion" in d else f" value {d['value']}") for d in s.dirichlet]
    lines += [f"load: {ld.get('name', '')} {ld['type']} {ld['value']} [{_fmt_region(ld['region'])}] "
              f"history {ld['history']}" for ld in s.loads]
    lines += [f"monitor: {m['name']} = {m['quantity']}" for m in s.monitors]
    lines += ["", f"analysis: {s.analysis}", "", "what is modelled, and why:", *plan.lines()]
    if s.paper:
        lines += ["", "the paper reports:", *[f"  {k} = {v}" for k, v in s.paper.items()]]
    return "\n".join(lines)


def paper_comparison(scene, table) -> pd.DataFrame:
    """Our final monitored values beside the paper's (``[paper.compare.<monitor>]`` tables
    with ``value`` and ``note``): monitor, ours, paper, ratio, note."""
    rows = []
    done = table[table["converged"]] if "converged" in table else table
    for name, ref in scene.paper.get("compare", {}).items():
        ours = float(done[name].iloc[-1]) if len(done) and name in done else float("nan")
        rows.append({"monitor": name, "ours": ours, "paper": ref["value"], "ratio": ours / ref["value"],
                     "note": ref.get("note", "")})
    return pd.DataFrame(rows, columns=["monitor", "ours", "paper", "ratio", "note"])
