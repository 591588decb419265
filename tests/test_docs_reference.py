"""The format reference pages of the documentation follow the code (issue 40).

The scene-format and spec-format pages (``docs/_generated/``) are generated at build time from the
schema tables the loaders check, the words beside them and the named limits
(``docs/_ext/tbdocs_formats.py``). These tests change a key or a limit in the code (monkeypatched)
and regenerate: the page must change with it, and a key the code accepts without words describing
it must stop the build instead of leaving a blank. The generators need no Sphinx."""
from __future__ import annotations

import sys
from pathlib import Path

import pytest

DOCS_EXT = Path(__file__).resolve().parents[1] / "docs" / "_ext"
sys.path.insert(0, str(DOCS_EXT))

import tbdocs_formats  # noqa: E402
from tissuebench.cases import schema as cases_schema, sections  # noqa: E402
from tissuebench.studies import limits, spec, training  # noqa: E402


def test_the_spec_page_follows_a_limit(monkeypatch):
    before = tbdocs_formats.spec_format()
    assert "| `latency_steps` | `2000` | an integer from 1 to 100000 |" in before
    monkeypatch.setitem(limits.LIMITS, "latency_steps", 4321)
    after = tbdocs_formats.spec_format()
    assert "| `latency_steps` | `2000` | an integer from 1 to 4321 |" in after
    assert "| `latency_steps` | 4,321 |" in after and "100,000 |" in after  # the limits table: warmup keeps its own


def test_the_spec_page_follows_a_kind_key(monkeypatch):
    before = tbdocs_formats.spec_format()
    path = training.TRAINING_KINDS["path"]
    monkeypatch.setitem(training.TRAINING_KINDS, "path", type(path)(**{**path.__dict__,
                                                                       "keys": path.keys | {"stride"}}))
    with pytest.raises(ValueError, match=r"training\.path: keys without a description \['stride'\]"):
        tbdocs_formats.spec_format()
    docs = dict(training.TRAINING_KIND_DOCS["path"][1], stride="another key")
    monkeypatch.setitem(training.TRAINING_KIND_DOCS, "path", (training.TRAINING_KIND_DOCS["path"][0], docs))
    after = tbdocs_formats.spec_format()
    assert "`stride`" not in before and "| `stride` |  | another key |" in after


def test_the_spec_page_follows_a_case_key(monkeypatch):
    monkeypatch.setattr(spec, "_CASE", spec._CASE - {"scaling_group"})
    with pytest.raises(ValueError, match=r"descriptions of no key \['scaling_group'\]"):
        tbdocs_formats.spec_format()


def test_the_scene_page_follows_a_limit(monkeypatch):
    before = tbdocs_formats.scene_format()
    assert "| `load_steps` | an integer from 1 to 100000 | required |" in before
    monkeypatch.setitem(sections._STATIC, "load_steps", cases_schema.c_int_range(1, 77))
    after = tbdocs_formats.scene_format()
    assert "| `load_steps` | an integer from 1 to 77 | required |" in after


def test_the_scene_page_follows_a_key(monkeypatch):
    before = tbdocs_formats.scene_format()
    monkeypatch.setitem(sections._DYNAMIC, "substeps", cases_schema.c_int1)
    with pytest.raises(ValueError, match=r"analysis \(dynamic\): keys without a description \['substeps'\]"):
        tbdocs_formats.scene_format()
    monkeypatch.setitem(sections.DYNAMIC_DOC, "substeps", "steps inside a step")
    after = tbdocs_formats.scene_format()
    assert "`substeps`" not in before
    assert "| `substeps` | an integer >= 1 |  | steps inside a step |" in after


def test_a_checker_must_say_what_it_accepts(monkeypatch):
    monkeypatch.setitem(sections._STATIC, "note", lambda path, v: v)  # a checker without `accepts`
    with pytest.raises(ValueError, match=r"analysis \(static\)\.note: its checker .* does not say what it accepts"):
        tbdocs_formats.scene_format()


def test_every_generated_page_is_complete():
    """Every schema table has its words today: the docs build would stop otherwise."""
    import tbdocs_pages

    assert tbdocs_formats.scene_format().count("\n## ") >= 15
    assert "## `[[method]]`" in tbdocs_formats.spec_format()
    for page in (tbdocs_pages.cli_reference(), tbdocs_pages.store_reference(), tbdocs_pages.methods_reference()):
        assert page.startswith("# ")
