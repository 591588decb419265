"""The scene-format and spec-format reference pages, generated from the code's own schema tables.

Each table of a scene file or a sweep spec is rendered from the dict the loader checks it with
(``{key: checker}`` or a key set), the words beside it (``*_DOC``), what each checker accepts
(:func:`tissuebench.cases.schema.accepts_text`) and the named limits, so the documented format is
the one the code checks: a key added, removed or bounded differently in the code changes these
pages (``tests/test_docs_reference.py``). A key without its words is an error, not a blank cell.

Pure Python (no Sphinx): the docs extension (:mod:`tbdocs`) writes what these functions return.
"""
from __future__ import annotations

import inspect
import json
import re


def cell(text) -> str:
    """``text`` made safe for one cell of a Markdown table (no newline, no bare ``|``)."""
    return " ".join(str(text).split()).replace("|", "\\|")


def table(header, rows) -> str:
    """A Markdown table (MyST) of ``rows`` under ``header``."""
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(cell(c) for c in row) + " |" for row in rows]
    return "\n".join(lines) + "\n"


def described(where: str, keys, docs: dict) -> dict:
    """``docs`` checked against ``keys``: every key has its words and no words lack a key."""
    missing, stale = sorted(set(keys) - set(docs)), sorted(set(docs) - set(keys))
    if missing or stale:
        raise ValueError(f"{where}: keys without a description {missing}, descriptions of no key {stale}: "
                         "add or remove them beside the schema")
    return docs


def key_table(where: str, schema: dict, docs: dict, required=(), defaults: dict | None = None) -> str:
    """Key | accepts | required | what, for a ``{key: checker}`` schema."""
    from tissuebench.cases.schema import accepts_text

    described(where, schema, docs)
    rows = []
    for key, checker in schema.items():
        accepts = accepts_text(checker)
        if not accepts:
            raise ValueError(f"{where}.{key}: its checker {checker!r} does not say what it accepts (schema.accepts)")
        need = "required" if key in required else (f"default `{toml_value(defaults[key])}`"
                                                     if defaults and key in defaults else "")
        rows.append((f"`{key}`", accepts, need, docs[key]))
    return table(("key", "accepts", "", "what"), rows)


def names(values) -> str:
    return ", ".join(f"`{v}`" for v in values)


def markdown(rst: str) -> str:
    """The inline markup of a docstring (reST: ``:func:`~a.b```, double backquotes) as Markdown."""
    text = re.sub(r":[a-z]+:`~?([^`]+)`", r"`\1`", rst)
    return text.replace("``", "`")


def first_paragraph(obj) -> str:
    """The first paragraph of ``obj``'s docstring, one line of Markdown."""
    doc = inspect.getdoc(obj) or ""
    return markdown(" ".join(doc.split("\n\n")[0].split()))


def toml_value(value) -> str:
    """``value`` as TOML writes it (tuples as arrays)."""
    try:
        return json.dumps(list(value) if isinstance(value, tuple) else value)
    except TypeError:
        return repr(value)


def _signature_defaults(fn) -> dict:
    return {p.name: p.default for p in inspect.signature(fn).parameters.values() if p.default is not p.empty}


# ----------------------------------------------------------------------------------------- scene
def scene_format() -> str:
    """The Markdown of the scene-format reference page."""
    from tissuebench.cases import (builder_params, builders, cutting, histories, monitors, parameters, regions,
                                   schema, scene, sections, variants)

    out = ["# Scene format\n",
           "A scene is a TOML file: a catalogue case (`tissuebench cases`) or a file of your own "
           "(`tissuebench scene check FILE` validates it and draws it). This page is generated from the tables "
           "the loader checks a scene with (`tissuebench.cases`), so it lists exactly the keys and values the "
           "loader accepts. Every error names the key path and the value (`material.nu = 0.7: expected a "
           "Poisson ratio in (-1, 0.5)`). Numbers are in the units of `[units]`.\n"]
    fe_required = ("case", "units", "mesh", "analysis", "dirichlet")
    arrays = ("dirichlet", "load", "monitor")  # arrays of tables
    described("scene top level", scene._TOP, scene.TOP_DOC)
    out += ["(scene-top)=\n## Top level\n",
            table(("table", "", "what"), [(f"`[[{k}]]`" if k in arrays else f"`[{k}]`",
                                           "required" if k in fe_required else "", scene.TOP_DOC[k])
                                          for k in sorted(scene._TOP)]),
            "A finite-element scene needs `[material]`, a 1D model `[model]`; any other top-level key is "
            "refused.\n"]
    out += ["(scene-case)=\n## `[case]`\n", key_table("case", scene._CASE_SCHEMA, scene.CASE_DOC,
                                                      required=("name", "description")),
            f"Models: {names(schema.MODELS)}.\n"]
    out += ["(scene-units)=\n## `[units]`\n", key_table("units", scene._UNITS_SCHEMA, scene.UNITS_DOC,
                                                        required=("length",))]
    out += ["(scene-mesh)=\n## `[mesh]`\n", "Either a builder of the package, with its parameters per "
            "resolution:\n", key_table("mesh", scene._MESH_SCHEMA, scene.MESH_DOC,
                                       required=("builder", "ci", "paper")),
            "or a mesh file of your own:\n",
            key_table("mesh (file)", scene._MESH_FILE_SCHEMA, scene.MESH_FILE_DOC, required=("file", "element")),
            "Length units of a mesh file (`unit`), in metres: "
            + ", ".join(f"`{u}` = {m:g}" for u, m in scene.LENGTH_UNITS.items())
            + ". One of `unit` or `scale` is required.\n"]
    out += ["(scene-builders)=\n### Mesh builders\n",
            f"A builder's parameters go in `[mesh.params]`, `[mesh.ci]` and `[mesh.paper]`; at most "
            f"{builder_params.MAX_CELLS:,} cells (estimated before meshing).\n"]
    for name, (params, required) in builder_params.BUILDER_PARAMS.items():
        fn = builders.BUILDERS.get(name)
        defaults = _signature_defaults(fn) if fn else {}
        rows = [(f"`{k}`", schema.accepts_text(c), "required" if k in required
                 else (f"default `{toml_value(defaults[k])}`" if k in defaults else "")) for k, c in params.items()]
        out += [f"`builder = \"{name}\"`: {first_paragraph(fn) if fn else ''}\n",
                table(("parameter", "accepts", ""), rows)]
    out += ["(scene-material)=\n## `[material]`\n",
            "Finite-element scenes. `name` chooses the law and so its parameters; every law also takes `density`."
            "\n"]
    param_keys = set().union(*map(set, sections.MATERIAL_SCHEMAS.values())) | {"name", "density"}
    docs = described("material", param_keys, sections.MATERIAL_DOC)
    for name, params in sections.MATERIAL_SCHEMAS.items():
        rows = [(f"`{k}`", schema.accepts_text(c), "" if k == "fibres" else "required", docs[k])
                for k, c in params.items()]
        rows.append(("`density`", schema.accepts_text(schema.c_pos), "dynamics", docs["density"]))
        out += [f"`name = \"{name}\"`\n", table(("key", "accepts", "", "what"), rows)]
    out += ["(scene-model)=\n## `[model]`\n", "1D models (`case.model`):\n"]
    model_keys = set().union(*(set(s) for s, _ in sections.MODEL_SCHEMAS.values()))
    docs = described("model", model_keys, sections.MODEL_DOC)
    for name, (params, required) in sections.MODEL_SCHEMAS.items():
        rows = [(f"`{k}`", schema.accepts_text(c), "required" if k in required else "", docs[k])
                for k, c in params.items()]
        out += [f"`model = \"{name}\"`\n", table(("key", "accepts", "", "what"), rows)]
    out += ["(scene-dirichlet)=\n## `[[dirichlet]]`\n",
            key_table("dirichlet", sections.DIRICHLET_SCHEMA, sections.DIRICHLET_DOC, required=("region",)),
            "A rotation (`motion`):\n",
            key_table("dirichlet.motion", sections._MOTION_SCHEMA, sections.MOTION_DOC,
                      required=tuple(sections._MOTION_SCHEMA))]
    out += ["(scene-load)=\n## `[[load]]`\n",
            key_table("load", sections.LOAD_SCHEMA, sections.LOAD_DOC, required=("type", "value")),
            "`region` is required but for a body load; 1D models take point loads only.\n"]
    out += ["(scene-analysis)=\n## `[analysis]`\n", "Static:\n",
            key_table("analysis (static)", sections._STATIC, sections.STATIC_DOC, required=("type", "load_steps")),
            "Dynamic:\n",
            key_table("analysis (dynamic)", sections._DYNAMIC, sections.DYNAMIC_DOC,
                      required=("type", "dt", "t_end", "integrator")),
            f"Integrators: {names(sections.INTEGRATOR_NAMES)}; `t_end / dt` at most "
            f"{sections.MAX_TIME_STEPS:,} steps.\n"]
    out += _integrator_options()
    out += ["(scene-monitor)=\n## `[[monitor]]`\n",
            key_table("monitor", monitors._MONITOR_SCHEMA, monitors.MONITOR_DOC, required=("name", "quantity"))]
    described("monitor quantities", monitors.MONITOR_QUANTITIES, monitors.MONITOR_QUANTITY_DOC)
    out += [table(("quantity", "needs", "what"), [(f"`{q}`", names(monitors._MONITOR_NEEDS.get(q, ())),
                                                  monitors.MONITOR_QUANTITY_DOC[q])
                                                 for q in monitors.MONITOR_QUANTITIES]),
            f"A monitor may not be named as a column of the result table: {names(scene.RESERVED_COLUMNS)}.\n"]
    out += ["(scene-regions)=\n## Regions\n",
            f"A region selects nodes by their coordinates: exactly one of {names(regions._REGION_PRIMARY)}, "
            "with the keys it needs, and the modifiers.\n",
            key_table("region", regions._REGION_SCHEMA, regions.REGION_DOC),
            table(("selector", "needs"), [(f"`{k}`", names(regions._REGION_NEEDS.get(k, ())))
                                          for k in regions._REGION_PRIMARY])]
    out += ["(scene-histories)=\n## Load histories\n",
            "`history = { type = ..., ... }` of a load: the load factor against time (dynamics) or pseudo-time "
            "(statics, where it equals the load factor). Default: "
            + ", ".join(f"`{k} = {v!r}`" for k, v in histories.DEFAULT_HISTORY.items()) + ".\n"]
    described("histories", histories._HISTORY_SCHEMAS, histories.HISTORY_DOC)
    for kind, (params, required) in histories._HISTORY_SCHEMAS.items():
        what, docs = histories.HISTORY_DOC[kind]
        out += [f"`type = \"{kind}\"`: {what}\n"]
        if params:
            out.append(key_table(f"history {kind}", params, docs, required=required))
    out += ["(scene-parameters)=\n## `[parameters]`\n", "`[parameters.position]` moves the point of one point "
            "load along a line (a study may evaluate the scene at any position of `range`):\n",
            key_table("parameters.position", parameters._POSITION, parameters.POSITION_DOC,
                      required=("load", "axis", "point", "range")),
            "A study evaluates a scene at parameters `mu` (`Scene.at(mu)`, a sweep case's `mu`): a "
            "`[parameters]` name, `load_scale` (every load's value multiplied), a key of the material "
            "(`nu`, `E` ...) or an analysis override:\n",
            key_table("analysis overrides", parameters.ANALYSIS_OVERRIDES, parameters.ANALYSIS_OVERRIDES_DOC)]
    out += ["(scene-paper)=\n## `[paper]`\n", "A free table of the paper's numbers, except "
            "`[paper.compare.<monitor>]`:\n",
            key_table("paper.compare", scene.PAPER_COMPARE_SCHEMA, scene.PAPER_COMPARE_DOC, required=("value",))]
    out += ["(scene-cut)=\n## `[cut]`\n", key_table("cut", cutting._CUT_SCHEMA, cutting.CUT_DOC,
                                                    required=("incisions",)),
            "Each incision:\n", key_table("cut.incisions", cutting._INCISION_SCHEMA, cutting.INCISION_DOC,
                                          required=("angle_deg", "radii"))]
    described("variants", variants.VARIANT_KEYS, variants.VARIANT_DOC)
    out += ["(scene-variants)=\n## `[variants.<name>]`\n",
            "A variant is merged over the base scene before validation, so it is checked like a scene written "
            "out in full (`--variant NAME`):\n",
            table(("key", "merge"), [(f"`{k}`", variants.VARIANT_DOC[k]) for k in sorted(variants.VARIANT_KEYS)])]
    return "\n".join(out)


def _integrator_options() -> list:
    from tissuebench.refsolvers.dynamics.registry import INTEGRATORS

    rows = []
    for name, cls in INTEGRATORS.items():
        params = [p for p in inspect.signature(cls.__init__).parameters.values() if p.name != "self"
                  and p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)]
        rows.append((f"`{name}`", ", ".join(f"`{p.name} = {toml_value(p.default)}`" if p.default is not p.empty
                                            else f"`{p.name}`" for p in params)))
    return ["`integrator_options` are the keyword arguments of the integrator's constructor:\n",
            table(("integrator", "options (defaults)"), rows)]


# ------------------------------------------------------------------------------------------ spec
def _protocol_accepts(key: str) -> str:
    """What ``check_protocol`` accepts for a protocol key: a count, or seconds for the budget."""
    from tissuebench.studies import limits
    if key in limits._PROTOCOL_MIN:
        return f"an integer from {limits._PROTOCOL_MIN[key]} to {limits.LIMITS[key]}"
    return f"a number of seconds > 0, at most {limits.LIMITS[key]}"


def spec_format() -> str:
    """The Markdown of the sweep-spec reference page."""
    from tissuebench.choices import RESOLUTIONS
    from tissuebench.rom import METHODS
    from tissuebench.studies import limits, spec, units
    from tissuebench.studies.evaluation import EVALUATION_KIND_DOCS, EVALUATION_KINDS
    from tissuebench.studies.training import TRAINING_KIND_DOCS, TRAINING_KINDS

    out = ["# Sweep-spec format\n",
           "A sweep spec is a TOML file (`tissuebench sweep SPEC.toml`; the shipped presets are specs: "
           "`tissuebench sweep --list`). Every (case, method, option set) it plans is a unit. This page is "
           "generated from the keys, kinds and limits the spec loader (`tissuebench.studies.spec`) checks, so "
           "it lists exactly what it accepts. Every error names the key and the value and lists the valid "
           "choices; the CLI exits 2 before any work.\n"]
    described("spec top level", spec._TOP, spec.TOP_DOC)
    out += ["(spec-top)=\n## Top level\n",
            table(("table", "", "what"), [(f"`[{k}]`" if k in ("sweep", "protocol") else f"`[[{k}]]`",
                                           "required" if k in ("case", "method") else "", spec.TOP_DOC[k])
                                          for k in ("sweep", "protocol", "case", "method")])]
    described("sweep", spec._SWEEP, spec.SWEEP_DOC)
    choices = {"resolution": names(RESOLUTIONS), "error_metric": names(spec.ERROR_METRICS)}
    out += ["(spec-sweep)=\n## `[sweep]`\n",
            table(("key", "accepts", "what"), [(f"`{k}`", choices.get(k, "a string"), spec.SWEEP_DOC[k])
                                               for k in ("name", "description", "resolution", "error_metric")])]
    described("error metrics", spec.ERROR_METRICS, spec.ERROR_METRICS_DOC)
    out += ["(spec-metrics)=\n### Error metrics\n",
            table(("metric", "what"), [(f"`{m}`", spec.ERROR_METRICS_DOC[m]) for m in spec.ERROR_METRICS])]
    described("protocol", units.DEFAULT_PROTOCOL, units.PROTOCOL_DOC)
    out += ["(spec-protocol)=\n## `[protocol]`\n",
            "Optional; a `[[method]]`'s `protocol` overrides it for that method.\n",
            table(("key", "default", "accepts", "what"),
                  [(f"`{k}`", f"`{v}`", _protocol_accepts(k), units.PROTOCOL_DOC[k])
                   for k, v in units.DEFAULT_PROTOCOL.items()])]
    described("case", spec._CASE, spec.CASE_DOC)
    order = ["name", "id", "variant", "backend", "resolution", "training", "evaluation", "mu", "mesh",
             "paper_points", "scaling_group"]
    order += sorted(spec._CASE - set(order))
    out += ["(spec-case)=\n## `[[case]]`\n",
            table(("key", "", "what"), [(f"`{k}`", "required" if k == "name" else "", spec.CASE_DOC[k])
                                        for k in order if k in spec._CASE]),
            f"Backends: {names(spec.BACKENDS)}. A case id names a results folder: letters, digits, `_`, `.`, `-`.\n",
            "`paper_points` entries:\n",
            key_table("paper_points", spec._PAPER_POINT, {"label": "the point's label",
                                                            "step_ms": "the published step [ms]",
                                                            "error": "the published error (a fraction)"},
                      required=tuple(spec._PAPER_POINT))]
    out += ["(spec-training)=\n### Training kinds\n",
            "`training = { kind = \"...\", ... }`: what the methods of a case learn from. A method learns from "
            "the kinds it declares (`training_kinds`).\n"]
    out += _kinds("training", TRAINING_KINDS, TRAINING_KIND_DOCS, limits.LIMITS,
                  learners=lambda k: sorted(n for n, c in METHODS.items() if k in c.training_kinds))
    out += ["(spec-evaluation)=\n### Evaluation kinds\n",
            "`evaluation = { kind = \"...\", ... }`: where the methods are measured, against the reference at "
            "every point. Default: the training's kind where it is an evaluation kind, else `map`.\n"]
    out += _kinds("evaluation", EVALUATION_KINDS, EVALUATION_KIND_DOCS, limits.LIMITS)
    described("method", spec._METHOD, spec.METHOD_DOC)
    out += ["(spec-method)=\n## `[[method]]`\n",
            table(("key", "", "what"), [(f"`{k}`", "required" if k == "name" else "", spec.METHOD_DOC[k])
                                        for k in ("name", "cases", "options", "grid", "list", "paper", "protocol")]),
            "The options each method takes, their types and defaults: [Methods](methods.md). An option's value "
            "is checked against the type its constructor declares, then by the constructor itself.\n"]
    out += ["(spec-limits)=\n## Limits\n",
            "Every count of a spec has a named maximum (`tissuebench.studies.limits.LIMITS`), so a typo cannot "
            "ask for a run that never ends:\n",
            table(("count", "at most"), [(f"`{k}`", f"{v:,}") for k, v in limits.LIMITS.items()]),
            f"At most {limits.MAX_UNITS:,} units per spec (counted before the grid is expanded; `--max-units` "
            f"raises it); an integer option at most {limits.MAX_OPTION_INT:,} in magnitude.\n"]
    return "\n".join(out)


# a key whose count is bounded under another name of LIMITS (limits.check_trajectory_evaluation)
_LIMIT_NAME = {("trajectory", "t_end"): ("trajectory_steps", "t_end / dt: ")}


def _limit(kind: str, key: str, doc: str, limits: dict) -> str:
    """The named maximum of a kind's key: ``LIMITS[key]`` (a flag, documented as `true`, has none)."""
    name, prefix = _LIMIT_NAME.get((kind, key), (key, ""))
    if name not in limits or doc.startswith("`true`"):
        return ""
    return f"{prefix}{limits[name]:,}"


def _kinds(what, registry, docs, limits, learners=None) -> list:
    described(f"{what} kinds", registry, docs)
    out = []
    for name, kind in registry.items():
        text, key_docs = docs[name]
        described(f"{what}.{name}", kind.keys, key_docs)
        line = f"`kind = \"{name}\"`: {text}."
        if learners is not None:
            line += f" Learnt from by: {names(learners(name)) or 'no registered method'}."
        out.append(line + "\n")
        if kind.keys:
            out.append(table(("key", "at most", "what"), [(f"`{k}`", _limit(name, k, key_docs[k], limits), key_docs[k])
                                                          for k in sorted(kind.keys)]))
    return out
