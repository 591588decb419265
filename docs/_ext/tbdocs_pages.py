"""Reference pages generated from the code: the command line, the store, the methods, the catalogue.

Pure Python (no Sphinx): the docs extension (:mod:`tbdocs`) writes what these functions return.
The command line is read from ``tissuebench.cli``'s argparse parser, the store from the column
schemas of ``tissuebench.studies.schema``, the methods from the registry (their constructors,
``Applies`` declarations and docstrings), the catalogue from the scene files, each picture drawn
by the code ``tissuebench scene check`` draws it with.
"""
from __future__ import annotations

import argparse
import dataclasses
import inspect
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from tbdocs_formats import described, first_paragraph, markdown, names, table, toml_value


# ------------------------------------------------------------------------------------------ cli
def _subcommands(parser):
    action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    helps = {a.dest: a.help for a in action._choices_actions}
    return [(name, helps.get(name, ""), sub) for name, sub in action.choices.items()]


def _argument_rows(parser):
    rows = []
    for a in parser._actions:
        if isinstance(a, argparse._HelpAction):
            continue
        flag = ", ".join(f"`{o}`" for o in a.option_strings) or f"`{a.metavar or a.dest.upper()}`"
        if a.option_strings and a.nargs != 0:
            flag += f" `{a.metavar or a.dest.upper()}`"
        what = (a.help or "").replace("%%", "%")
        if a.choices:
            what += (" " if what else "") + f"(one of {names(a.choices)})"
        default = "" if a.default in (None, False, argparse.SUPPRESS) or not a.option_strings else f"`{a.default}`"
        rows.append((flag, default, what))
    return rows


def cli_reference() -> str:
    """The Markdown of the command-line reference, read from the parser ``tissuebench`` runs."""
    from tissuebench import cli

    parser = cli._parser()
    out = ["# Command line\n",
           "Generated from the argparse parser of `tissuebench` (`tissuebench.cli`); `tissuebench COMMAND "
           "--help` prints the same. Exit status, for every command: 0 success, 1 a numerical failure (stored) "
           "or results that could not be written, 2 bad input (one line naming the option, key, value or path), "
           "130 interrupted.\n", table(("command", "what"), [(f"[`{n}`](#cli-{n})", h) for n, h, _ in
                                                             _subcommands(parser)])]
    for name, help_text, sub in _subcommands(parser):
        usage = " ".join(sub.format_usage().split())
        usage = usage[len("usage: "):] if usage.startswith("usage: ") else usage
        out += [f"(cli-{name})=\n## `tissuebench {name}`\n", f"{help_text}.\n" if help_text else "",
                "```text\n" + usage + "\n```\n", table(("argument", "default", "what"), _argument_rows(sub))]
    return "\n".join(out)


# ---------------------------------------------------------------------------------------- store
def store_reference() -> str:
    """The Markdown of the results-store reference, from the column schemas."""
    from tissuebench.studies import results, schema

    out = ["# Results store\n",
           "Generated from `tissuebench.studies.schema`, where the columns are declared once for the store, "
           "the report and the gate. `pandas.read_parquet(DIR)` reads the unit rows of a sweep's folder; "
           "`tissuebench.studies.results.read_points` / `read_outputs` / `read_latency` read the others, "
           "checking every file like user input.\n",
           "```{eval-rst}\n.. automodule:: tissuebench.studies.results\n   :no-members:\n```\n"]
    tables = (("units", "one row per unit: `DIR/case=<id>/method=<name>/<key>.parquet`", schema.UNIT_COLUMNS,
               schema.UNIT_COLUMNS_DOC),
              ("points", "one row per evaluation point: `DIR/_points/...`", schema.POINT_COLUMNS,
               schema.POINT_COLUMNS_DOC),
              ("outputs", "one row per (point, monitored output): `DIR/_outputs/...`", schema.OUTPUT_COLUMNS,
               schema.OUTPUT_COLUMNS_DOC),
              ("latency", "one row per timed haptic step: `DIR/_latency/...`", schema.LATENCY_COLUMNS,
               schema.LATENCY_COLUMNS_DOC))
    for name, where, columns, docs in tables:
        described(f"store {name}", columns, docs)
        out += [f"(store-{name})=\n## {name.capitalize()}\n", f"{where}; "
                f"partition columns {names(schema.PARTITIONS)} from the folder names.\n" if name == "units"
                else f"{where}.\n",
                table(("column", "type", "what"), [(f"`{c}`", str(t), docs[c]) for c, t in columns.items()])]
    assert results.read_units  # the readers named above exist
    return "\n".join(out)


# -------------------------------------------------------------------------------------- methods
def _options(cls):
    from tissuebench.studies.limits import _declared

    rows = []
    for p in inspect.signature(cls.__init__).parameters.values():
        if p.name == "self" or p.kind not in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY):
            continue
        default = "" if p.default is p.empty else f"`{toml_value(p.default)}`"
        rows.append((f"`{p.name}`", _declared(p) or "any", default, "nested" if p.name in cls.nested else ""))
    return rows


def _applies(cls) -> str:
    from tissuebench.rom.base import Applies

    base, a = Applies(), cls.applies
    said = [f"`{f.name} = {toml_value(getattr(a, f.name))}`" for f in dataclasses.fields(Applies)
            if getattr(a, f.name) != getattr(base, f.name)]
    return ", ".join(said) or "the defaults (any finite-element scene)"


def methods_reference() -> str:
    """The Markdown of the registered methods: options, training kinds, what each needs of a scene."""
    from tissuebench.rom import METHODS

    out = ["# Methods\n",
           "Generated from the registry (`tissuebench.rom.METHODS`): each method's options are its "
           "constructor's keyword arguments (a sweep checks a value against the declared type, then the "
           "constructor's own checks), its training kinds and model kind are class attributes, and what it "
           "needs of a scene is its `Applies` declaration (checked by `tissuebench methods SCENE` and when a spec "
           "loads). `nested` options are sliced from one build of their largest value. The method families "
           "and their papers: [Method families](../explanation/methods.md).\n",
           table(("method", "model kind", "learns from", "needs (`Applies`, non-default fields)"),
                 [(f"[`{n}`](#method-{n})", c.kind, names(c.training_kinds), _applies(c))
                  for n, c in sorted(METHODS.items())])]
    for name, cls in sorted(METHODS.items()):
        out += [f"(method-{name})=\n## `{name}`\n", f"`{cls.__module__}.{cls.__qualname__}`: "
                f"{first_paragraph(cls)}\n"]
        rows = _options(cls)
        out.append(table(("option", "type", "default", ""), rows) if rows else "No options.\n")
    return "\n".join(out)


# ------------------------------------------------------------------------------------ catalogue
def _leading_comment(path: Path) -> str:
    lines = []
    for line in path.read_text(encoding="utf-8").splitlines():
        if not line.startswith("#"):
            break
        lines.append(line.lstrip("#").strip())
    return " ".join(lines)


def _presets_using(name: str) -> list:
    import tomllib

    from tissuebench.studies.spec import PRESETS_DIR

    used = []
    for p in sorted(PRESETS_DIR.glob("*.toml")):
        cases = tomllib.loads(p.read_text()).get("case", [])
        if any(c.get("name") == name for c in cases):
            used.append(p.stem)
    return used


def _draw(name: str, folder: Path) -> str:
    """``folder/<name>.png`` drawn as ``tissuebench scene check`` draws it (kept while the scene's
    content hash and the drawing code are unchanged); returns the file name, or "" for a 1D model."""
    import hashlib

    from tissuebench.cases.scene import load
    from tissuebench.reports import scene_figure
    from tissuebench.studies.scene_check import scene_summary

    scene = load(name)
    if not scene.is_fe:
        return ""
    png, stamp = folder / f"{name}.png", folder / f"{name}.key"
    key = hashlib.sha256((scene.content_hash() + Path(scene_figure.__file__).read_text()).encode()).hexdigest()
    if not (png.is_file() and stamp.is_file() and stamp.read_text() == key):
        scene_figure.draw_scene(scene, scene_summary(scene), png)
        stamp.write_text(key)
    return png.name


def catalogue_reference(folder: Path, workers: int = 2) -> str:
    """The Markdown of the catalogue, one section per scene; pictures drawn into ``folder``."""
    from tissuebench.cases.scene import CATALOGUE_DIR, list_cases, load

    folder.mkdir(parents=True, exist_ok=True)
    names_ = list_cases()
    with ThreadPoolExecutor(workers) as pool:  # each picture renders in a child process
        pictures = dict(zip(names_, pool.map(lambda n: _draw(n, folder), names_)))
    out = ["# Catalogue\n",
           "The scenes shipped with tissuebench (`tissuebench cases`), generated from their files in "
           "`tissuebench/cases/catalogue/`. Each picture is drawn at ci resolution by the code "
           "`tissuebench scene check` uses: constrained nodes red, loads as orange arrows, monitors blue. "
           "[The scene format](scene-format.md) says what every key means; the papers of the sources are listed "
           "in [the method families](../explanation/methods.md).\n"]
    for name in names_:
        scene, path = load(name), CATALOGUE_DIR / f"{name}.toml"
        variants = ", ".join(f"`{v}`" for v in scene.variants) or "none"
        rows = [("source", markdown(scene.case.get("paper", "")) or "(none)"),
                ("what it models", scene.case["description"]),
                ("analysis", f"{scene.analysis['type']}, " + (f"material `{scene.material['name']}`"
                                                              if scene.material else f"1D model `{scene.model}`")),
                ("mesh", scene.mesh_label), ("variants", variants),
                ("monitors", names(m["name"] for m in scene.monitors) or "none"),
                ("in the presets", names(_presets_using(name)) or "none")]
        compare = scene.paper.get("compare", {})
        if compare:
            rows.append(("compared with the paper", "; ".join(f"`{k}`: {v['value']:g}" + (f" ({v['note']})"
                                                              if v.get("note") else "") for k, v in compare.items())))
        out += [f"(catalogue-{name})=\n## `{name}`\n", _leading_comment(path) + "\n", table(("", ""), rows)]
        if pictures[name]:
            out.append(f"```{{image}} {pictures[name]}\n:alt: the {name} scene at ci resolution\n:width: 80%\n```\n")
        else:
            out.append("A 1D model: no mesh to draw.\n")
    return "\n".join(out)


WORKFLOW = (("scene", "a TOML file:\nmesh, material,\nsupports, loads"),
            ("references", "full nonlinear FE,\ntwo backends,\ncached by content"),
            ("methods", "every ROM and\nbaseline that\napplies"),
            ("sweep", "error on held-out\nstates, latency\nof the haptic step"),
            ("report", "which method\nmeets 500 Hz / 2 %"),
            ("gate", "CI fails a less\naccurate or\nslower method"))


def draw_workflow(path: Path) -> None:
    """The workflow picture (SVG): scene -> references -> methods -> sweep -> report -> gate."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(12, 2.2))
    ax.set_xlim(0, 6 * 2.0)
    ax.set_ylim(0, 2.2)
    ax.axis("off")
    for i, (name, what) in enumerate(WORKFLOW):
        x = 0.15 + 2.0 * i
        ax.add_patch(plt.Rectangle((x, 0.15), 1.6, 1.9, facecolor="#eef3fb", edgecolor="#3b6ea8", lw=1.5))
        ax.text(x + 0.8, 1.75, name, ha="center", va="center", fontsize=12, weight="bold", color="#1d3f66")
        ax.text(x + 0.8, 0.85, what, ha="center", va="center", fontsize=8.5, color="#222222")
        if i:
            ax.annotate("", xy=(x, 1.1), xytext=(x - 0.4, 1.1), arrowprops={"arrowstyle": "->", "lw": 1.5})
    fig.savefig(path, format="svg", bbox_inches="tight", metadata={"Date": None})
    plt.close(fig)


def write_all(folder: Path) -> dict:
    """Write every generated reference page into ``folder``; returns ``{file: text}`` written."""
    from tbdocs_formats import scene_format, spec_format

    folder.mkdir(parents=True, exist_ok=True)
    pages = {"cli.md": cli_reference(), "scene-format.md": scene_format(), "spec-format.md": spec_format(),
             "store.md": store_reference(), "methods.md": methods_reference(),
             "catalogue.md": catalogue_reference(folder)}
    draw_workflow(folder / "workflow.svg")
    for name, text in pages.items():
        target = folder / name
        if not target.is_file() or target.read_text(encoding="utf-8") != text:  # unchanged pages stay unread
            target.write_text(text, encoding="utf-8")
    return pages


__all__ = ["cli_reference", "store_reference", "methods_reference", "catalogue_reference", "write_all"]
