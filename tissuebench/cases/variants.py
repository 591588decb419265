"""Variants of a scene file: ``[variants.<name>]`` tables merged over the base scene.

material/model/analysis/mesh replace the base table, dirichlet/load/monitor append to
the base arrays, paper/case/parameters merge key by key; ``description`` documents the
variant only. The merge works on the raw TOML tables, before validation, so a variant
is validated exactly like a scene written out in full.
"""
from __future__ import annotations

import copy

from .schema import c_table

__all__ = ["VARIANT_KEYS", "apply_variant"]

VARIANT_KEYS = {"description", "material", "model", "mesh", "analysis", "dirichlet", "load", "monitor", "paper",
                "case", "parameters"}


def apply_variant(raw, variant, path):
    """``(merged raw scene, variant name)``; ``variant=None`` picks ``case.default_variant``
    or else the first variant, and a scene without variants is returned as is."""
    variants = raw.get("variants", {})
    c_table("variants", variants)
    if variant is None:
        variant = raw.get("case", {}).get("default_variant") or (next(iter(variants)) if variants else None)
    if variant is None:
        return raw, None
    if variant not in variants:
        raise ValueError(f"variant {variant!r} of {path}: valid: {sorted(variants)}")
    over = c_table(f"variants.{variant}", variants[variant])
    # a deep copy: the merged tables are normalised in place by the validation
    out = copy.deepcopy({k: v for k, v in raw.items() if k != "variants"})
    for key, val in over.items():
        if key not in VARIANT_KEYS:
            raise ValueError(f"variants.{variant}.{key}: unknown key (valid: {sorted(VARIANT_KEYS)})")
        if key == "description":
            continue
        if key in ("dirichlet", "load", "monitor"):
            out[key] = list(out.get(key, [])) + list(val)
        elif key in ("paper", "case", "parameters"):
            out[key] = {**out.get(key, {}), **val}
        else:
            out[key] = copy.deepcopy(val)
    return out, variant
