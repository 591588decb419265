"""Property-based fuzzing of every input a user writes: scenes, sweep specs, mesh files.

Every catalogue scene and every shipped sweep preset is mutated (wrong types, NaN/inf, huge
and tiny numbers, unicode, path-like and markup strings, missing and unknown keys, empty
tables, see ``tests/_fuzz.py``), written back as TOML and read by the loader. Every input
either loads, or raises ValueError/TypeError whose message names the key (and the value);
any other exception fails the test (hypothesis shrinks it to a minimal scene).
Meshes with degenerate, inverted, folded, duplicate or disconnected cells go through
:func:`tissuebench.cases.io.read_mesh` the same way.

Profiles (tests/conftest.py): ``ci`` (default, seeded) and ``fuzz`` (``--hypothesis-profile=fuzz``,
5x the examples). The counts (tried / accepted / rejected) are printed at the end of the module
and appended to ``$TISSUEBENCH_FUZZ_REPORT`` when it is set.
"""
from __future__ import annotations

import tomllib

import meshio
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from _fuzz import Tally, dumps, mutate, names_a_key, vocabulary
from tissuebench.cases.io import read_mesh
from tissuebench.cases.meshes import box_mesh
from tissuebench.cases.scene import CATALOGUE_DIR, list_cases, load
from tissuebench.studies.describe import describe
from tissuebench.studies.reference.plan import plan_for
from tissuebench.studies.spec import PRESETS_DIR, expand_units, load_spec

pytestmark = pytest.mark.fuzz

SCENES = {name: tomllib.loads((CATALOGUE_DIR / f"{name}.toml").read_text()) for name in list_cases()}
PRESETS = {p.stem: tomllib.loads(p.read_text()) for p in sorted(PRESETS_DIR.glob("*.toml"))}
SCENE_WORDS = vocabulary(*SCENES.values())
SPEC_WORDS = vocabulary(*PRESETS.values()) + list_cases()
SCENE_KEYS = ["case", "units", "mesh", "material", "model", "dirichlet", "load", "analysis", "monitor", "paper",
              "variants", "cut", "parameters", "variant", "resolution"]
SPEC_KEYS = ["sweep", "protocol", "case", "method", "resolution"]
# describe() builds the mesh: only scenes whose ci mesh is cheap to build, with fewer examples
CHEAP_MESH = [n for n, d in SCENES.items() if d["mesh"]["builder"] in ("box", "cornea_dome", "interval", "beam1d")]
_HEALTH = [HealthCheck.function_scoped_fixture, HealthCheck.too_slow]
FEW = settings(max_examples=max(5, settings.default.max_examples // 10), suppress_health_check=_HEALTH)
FUZZ = settings(suppress_health_check=_HEALTH)


@pytest.fixture(scope="module", autouse=True)
def fuzz_report():
    yield
    Tally.write()


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    return tmp_path_factory.mktemp("fuzz")


def _verdict(test, call, keys):
    """Run ``call``: 'accepted', or 'rejected' for a ValueError/TypeError naming a key; anything
    else is counted as 'other' and re-raised (the test fails). ``keys``: the key names a
    message may start its key path with, or a predicate on the message."""
    named = keys if callable(keys) else (lambda msg: names_a_key(msg, keys))
    try:
        call()
    except (ValueError, TypeError) as exc:
        if not named(str(exc)):
            Tally.add(test, "other")
            raise AssertionError(f"{type(exc).__name__} names no key: {exc}") from exc
        Tally.add(test, "rejected")
        return "rejected"
    except BaseException:
        Tally.add(test, "other")
        raise
    Tally.add(test, "accepted")
    return "accepted"


def _scene_call(path, data, variants):
    variant = data.draw(st.one_of(st.none(), st.sampled_from(variants or ["none"]), st.sampled_from(SCENE_WORDS)),
                        label="variant")
    resolution = data.draw(st.sampled_from(["ci", "ci", "paper", "fine"]), label="resolution")

    def call():
        scene = load(path, resolution=resolution, variant=variant)
        plan_for(scene)
        scene.content_hash()
        if scene.loads and all(ld["history"] == scene.loads[0]["history"] for ld in scene.loads):
            scene.history(np.linspace(0.0, 1.0, 5))
    return call


@pytest.mark.parametrize("case", sorted(SCENES))
@FUZZ
@given(data=st.data())
def test_mutated_scenes_load_or_name_the_key(case, folder, data):
    doc, _ = mutate(data, SCENES[case], SCENE_WORDS)
    path = folder / f"{case}.toml"
    path.write_text(dumps(doc))
    _verdict("scene load", _scene_call(path, data, list(SCENES[case].get("variants", {}))), SCENE_KEYS)


@pytest.mark.parametrize("case", CHEAP_MESH)
@FEW
@given(data=st.data())
def test_mutated_scenes_describe_or_name_the_key(case, folder, data):
    # the mesh tables are left alone here: describe() meshes, and their values are fuzzed by
    # the load test above (the builders' parameters are validated when the scene loads)
    doc, _ = mutate(data, SCENES[case], SCENE_WORDS, protect=("mesh",))
    for v in doc.get("variants", {}).values() if isinstance(doc.get("variants"), dict) else ():
        if isinstance(v, dict):
            v.pop("mesh", None)
    path = folder / f"describe_{case}.toml"
    path.write_text(dumps(doc))
    _verdict("scene describe", lambda: describe(path), SCENE_KEYS)


@pytest.mark.parametrize("preset", sorted(PRESETS))
@settings(FUZZ)
@given(data=st.data())
def test_mutated_sweep_specs_load_or_name_the_key(preset, folder, data):
    doc, _ = mutate(data, PRESETS[preset], SPEC_WORDS)
    path = folder / f"spec_{preset}.toml"
    path.write_text(dumps(doc))
    resolution = data.draw(st.sampled_from([None, None, "ci", "paper", "fine"]), label="resolution")
    _verdict("sweep spec", lambda: expand_units(load_spec(path, resolution=resolution)), SPEC_KEYS)


# ------------------------------------------------------------------------------ meshes
def _base_mesh(cell_type):
    m = box_mesh((1.0, 1.0, 1.0), (2, 2, 2), cell_type)
    return m.points.copy(), m.cells.copy()


MESH_DEFECTS = ("collapse", "swap", "mirror_all", "duplicate_cell", "duplicate_point", "disconnected",
                "out_of_range", "nan", "huge", "tiny", "drop_cells", "flat", "move_through", "mixed_blocks",
                "surface_only", "permute")


def _apply_defect(data, pts, cells, cell_type, defect):
    n = len(cells)
    i = data.draw(st.integers(0, n - 1), label="cell")
    if defect == "collapse":  # two vertices of a cell at the same place: zero volume
        pts[cells[i, 1]] = pts[cells[i, 0]]
    elif defect == "swap":  # node order of some cells reversed: mixed orientation, same geometry
        k = data.draw(st.integers(1, n), label="n_swapped")
        cells[:k, [1, 2]] = cells[:k, [2, 1]] if cell_type == "tetra" else cells[:k, [3, 1]]
    elif defect == "mirror_all":
        pts[:, 0] *= -1.0
    elif defect == "duplicate_cell":
        cells = np.vstack([cells, cells[i]])
    elif defect == "duplicate_point":
        pts = np.vstack([pts, pts[cells[i, 0]]])
        cells[i, 0] = len(pts) - 1
    elif defect == "disconnected":
        cells = np.vstack([cells, cells[:1] + len(pts)])
        pts = np.vstack([pts, pts + 10.0])
    elif defect == "out_of_range":
        cells[i, 0] = data.draw(st.sampled_from([-1, len(pts), 10 ** 6]), label="index")
    elif defect == "nan":
        pts[cells[i, 0], data.draw(st.integers(0, 2), label="axis")] = data.draw(
            st.sampled_from([np.nan, np.inf, -np.inf]), label="bad")
    elif defect == "huge":
        with np.errstate(over="ignore"):
            pts *= data.draw(st.sampled_from([1e100, 1e200, 1e307]), label="scale")
    elif defect == "tiny":
        pts *= data.draw(st.sampled_from([1e-100, 1e-200, 1e-310]), label="scale")
    elif defect == "drop_cells":
        cells = cells[: data.draw(st.integers(0, n - 1), label="kept")]
    elif defect == "flat":
        pts[:, data.draw(st.integers(0, 2), label="axis")] = 0.0
    elif defect == "move_through":  # a vertex pushed through its neighbours: a fold
        v = cells[i, 0]
        centre = pts.mean(axis=0)
        pts[v] = centre + data.draw(st.sampled_from([-1.0, -2.0, -0.5]), label="through") * (pts[v] - centre)
    elif defect == "permute":
        order = np.asarray(data.draw(st.permutations(range(cells.shape[1])), label="order"))
        cells[i] = cells[i, order]
    return pts, cells


@pytest.mark.parametrize("cell_type", ["tetra", "hexahedron"])
@FUZZ
@given(data=st.data())
def test_defective_meshes_read_or_name_the_cells(cell_type, folder, data):
    pts, cells = _base_mesh(cell_type)
    blocks = [(cell_type, cells)]
    defects = data.draw(st.lists(st.sampled_from(MESH_DEFECTS), min_size=1, max_size=3), label="defects")
    # an index out of range last: the other defects index the points through the cells
    for d in sorted(defects, key=lambda d: d == "out_of_range"):
        if d == "mixed_blocks":
            other = "hexahedron" if cell_type == "tetra" else "tetra"
            o_pts, o_cells = _base_mesh(other)
            blocks.append((other, o_cells + len(pts)))
            pts = np.vstack([pts, o_pts + 5.0])
        elif d == "surface_only":
            blocks = [("triangle", cells[:, :3])]
        elif blocks[0][0] == cell_type and len(blocks[0][1]):
            pts, cells = _apply_defect(data, pts, blocks[0][1].copy(), cell_type, d)
            blocks[0] = (cell_type, cells)
    path = folder / f"mesh_{cell_type}.vtu"
    try:
        meshio.Mesh(pts, [b for b in blocks if len(b[1])]).write(path)
    except Exception:  # noqa: BLE001 - meshio refuses to write it: not a file a user could hold
        return
    choice = data.draw(st.sampled_from([None, None, cell_type, "wedge"]), label="cell_type")
    what = ("cells", "points", "cell_type", "cell blocks", "cannot read it")
    _verdict("mesh file", lambda: read_mesh(path, cell_type=choice),
             lambda msg: (str(path) in msg or "cell_type" in msg) and any(w in msg for w in what))
