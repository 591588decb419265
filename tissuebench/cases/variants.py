"""Variants of a scene file: ``[variants.<name>]`` tables merged over the base scene.

material/model/analysis/mesh replace the base table, dirichlet/load/monitor append to
the base arrays, paper/case/parameters merge key by key; ``histories`` (a table of load
name -> history table) replaces the history of the loads of that ``name`` (the base's and the
variant's): a dynamic variant of a static scene, ``analysis`` replaced and the probe given a
``ramp_hold_release``, needs no second file. ``description`` documents the variant only. The
merge works on the raw TOML tables, before validation, so a variant is validated exactly like a
scene written out in full.
"""
from __future__ import annotations

import copy

from .schema import c_table, fail, key_text

__all__ = ["VARIANT_KEYS", "apply_variant"]

VARIANT_KEYS = {"description", "material", "model", "mesh", "analysis", "dirichlet", "load", "monitor", "paper",
                "case", "parameters", "histories"}
# how each key of a variant merges (the scene-format reference of the documentation)
VARIANT_DOC = {**{k: "replaces the base table" for k in ("material", "model", "mesh", "analysis")},
               **{k: "appended to the base array" for k in ("dirichlet", "load", "monitor")},
               **{k: "merged key by key over the base table" for k in ("paper", "case", "parameters")},
               "histories": "a table {load name = history table}: replaces those named loads' histories",
               "description": "documentation of the variant"}


def apply_variant(raw, variant, path):
    """``(merged raw scene, variant name)``; ``variant=None`` picks ``case.default_variant``,
    else the base scene as written (a ``[variants.*]`` table added to a scene never silently
    becomes its default: a static scene stays static until a variant is asked for).

    ValueError names the offending key (``variants.<name>.<key>``, ``case.default_variant``)
    or the ``variant`` argument, with the value and the valid choices."""
    variants = c_table("variants", raw.get("variants", {}))
    case = raw.get("case", {})
    if variant is None:
        default = case.get("default_variant") if isinstance(case, dict) else None
        if default is not None and (not isinstance(default, str) or default not in variants):
            fail("case.default_variant", default, f"not a variant of the scene; valid: {sorted(variants)}")
        variant = default
    if variant is None:
        return raw, None
    if not isinstance(variant, str) or variant not in variants:
        fail("variant", variant, f"not a variant of {path}; valid: {sorted(variants)}")
    over = c_table(f"variants.{key_text(variant)}", variants[variant])
    # a deep copy: the merged tables are normalised in place by the validation
    out = copy.deepcopy({k: v for k, v in raw.items() if k != "variants"})
    for key, val in over.items():
        where = f"variants.{key_text(variant)}.{key_text(key)}"
        if key not in VARIANT_KEYS:
            raise ValueError(f"{where}: unknown key (valid: {sorted(VARIANT_KEYS)})")
        if key in ("description", "histories"):  # histories: once the loads are merged
            continue
        if key in ("dirichlet", "load", "monitor"):
            if not isinstance(val, list):
                fail(where, val, f"expected an array of tables ([[variants.{key_text(variant)}.{key}]]), "
                     "appended to the scene's")
            base = out.get(key, [])
            out[key] = (list(base) if isinstance(base, list) else [base]) + list(val)
        elif key in ("paper", "case", "parameters"):
            c_table(where, val)
            base = out.get(key, {})
            out[key] = {**base, **val} if isinstance(base, dict) else base  # a bad base is named later
        else:
            out[key] = copy.deepcopy(val)
    if "histories" in over:
        _replace_histories(out, over["histories"], f"variants.{key_text(variant)}.histories")
    return out, variant


def _replace_histories(raw, histories, where):
    """Give every load named in ``histories`` its history there (checked later, with the loads)."""
    histories = c_table(where, histories)
    loads = raw.get("load", [])
    loads = loads if isinstance(loads, list) else []  # a bad array is named by the validation
    named = [ld.get("name") for ld in loads if isinstance(ld, dict) and "name" in ld]
    for name, history in histories.items():
        hit = [ld for ld in loads if isinstance(ld, dict) and ld.get("name") == name]
        if not hit:
            fail(f"{where}.{key_text(name)}", history, f"no load is named {name!r}; named loads: {named} (give the "
                 "load a name to replace its history)")
        for ld in hit:
            ld["history"] = copy.deepcopy(history)
