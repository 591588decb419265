"""``check --against REF`` on the repository of the code under test (issue 39), fast: which
repository REF is found in, where the project's packages are at REF (src/ layouts, a package
moved, a non-editable install mapped by its packaging), REF's entry points, and REF's
processes taking REF's copy of a plugin or naming the copy they took instead. End to end
through the CLI: tests/studies/test_gate_own_repo.py (slow)."""
from __future__ import annotations

import pytest

from tissuebench.gate import HEAD_ROOT
from tissuebench.gate.sides import Code, foreign
from tissuebench.gate.project import export_project, find_project, git_top
from tissuebench.gate.ref import _methods_of, run_ref_sweep

from _gate_repo import commit, git, init
from _plugin_dist import forget_modules, on_path

PLUGIN = ('from tissuebench.rom.baselines import Nearest\n\n\nclass {cls}(Nearest):\n    name = "{name}"\n')


def _pyproject(dist, version="1.0", where=None, points=None, dynamic=False):
    text = f'[project]\nname = "{dist}"\n' + ('dynamic = ["version"]\n' if dynamic else f'version = "{version}"\n')
    if points:
        text += '\n[project.entry-points."tissuebench.methods"]\n' + "".join(f'{k} = "{v}"\n' for k, v in
                                                                            points.items())
    if where is not None:
        text += f'\n[tool.setuptools.packages.find]\nwhere = ["{where}"]\n'
    return text


@pytest.fixture
def importable(monkeypatch):
    """Put folders first on the path of this process and of those it starts (a package's import
    location, as an install does); the test packages ``tbp_*`` are forgotten after."""
    yield lambda folder: on_path(monkeypatch, folder)
    forget_modules("tbp_*")


def test_the_project_is_the_plugins_repository_else_the_working_directorys(tmp_path, importable, monkeypatch):
    """The user's gate once took REF from tissuebench's repository ("... is not a commit of
    .../tissuebench", or silently tissuebench's HEAD~1): REF is now found where the code under
    test is, and the output says which and why."""
    plugin = init(tmp_path / "plugin")
    commit(plugin, {"pyproject.toml": _pyproject("tbp-a", where="src"), "src/tbp_a/__init__.py": "",
                    "src/tbp_a/m.py": PLUGIN.format(cls="A", name="tbp_a")})
    importable(plugin / "src")
    other = init(tmp_path / "other")
    commit(other, {"README": "x"})
    monkeypatch.chdir(other)
    methods = [("tbp_a.m:A", "tbp-a")]
    found = find_project(methods, HEAD_ROOT)
    assert found.repo == plugin.resolve() and "the package tbp_a of the sweep's plugin methods" in found.how
    assert f"the working directory is in another one, {other.resolve()} (--project to gate that)" in found.how
    assert [(p.name, p.folder) for p in found.packages] == [("tbp_a", "src")]
    assert set(found.outside) == {"tissuebench"}  # the same on both sides
    assert find_project([], HEAD_ROOT).repo == other.resolve()  # no plugin method: the working directory's
    assert find_project([], HEAD_ROOT).how == "the working directory's repository"
    given = find_project(methods, HEAD_ROOT, project=other / "README")
    assert given.repo == other.resolve() and given.how == "given by --project" and given.packages == ()
    with pytest.raises(ValueError, match=rf"--project = '{tmp_path / 'plain'}': not inside a git checkout"):
        (tmp_path / "plain").mkdir()
        find_project(methods, HEAD_ROOT, project=tmp_path / "plain")
    # nowhere: the plugin outside any repository, the working directory too
    loose = tmp_path / "loose"
    (loose / "tbp_z").mkdir(parents=True)
    (loose / "tbp_z" / "__init__.py").write_text("")
    importable(loose)
    monkeypatch.chdir(tmp_path / "plain")
    if git_top(HEAD_ROOT / "tissuebench") is not None:  # tissuebench's own methods: its repository, as before
        assert find_project([], HEAD_ROOT).repo == git_top(HEAD_ROOT / "tissuebench")
    with pytest.raises(ValueError, match=rf"no git repository to find REF in: the working directory "
                                         rf"{tmp_path / 'plain'} is not in a git checkout and neither is a plugin "
                                         rf"package \(tbp_z is imported from {loose}\); give --project PATH"):
        find_project([("tbp_z.m:Z", None)], HEAD_ROOT)


def test_a_package_is_exported_where_refs_packaging_puts_it(tmp_path, importable, monkeypatch):
    """A flat layout at REF, src/ at HEAD (read from REF's pyproject), a setup.cfg package_dir,
    and a commit without the package: each side's folder, REF's version and entry points."""
    repo = init(tmp_path / "repo")
    flat = commit(repo, {"pyproject.toml": _pyproject("tbp-m", "1.0", points={"tbp_m": "tbp_m.core:M"}),
                         "tbp_m/__init__.py": "VERSION = 1\n", "tbp_m/core.py": PLUGIN.format(cls="M", name="tbp_m")})
    cfg = commit(repo, {"pyproject.toml": None, "tbp_m": None, "lib/tbp_m/__init__.py": "VERSION = 2\n",
                        "setup.cfg": "[metadata]\nname = tbp-m\nversion = 2.0\n[options]\npackage_dir =\n    =lib\n"
                                     "[options.entry_points]\ntissuebench.methods =\n    tbp_m = tbp_m.core:M\n"})
    none = commit(repo, {"setup.cfg": None, "lib": None, "README": "nothing"})
    commit(repo, {"README": None, "pyproject.toml": _pyproject("tbp-m", "3.0", where="src", dynamic=True),
                  "src/tbp_m/__init__.py": "VERSION = 3\n__version__ = '3.0.dev'\n"})
    importable(repo / "src")
    monkeypatch.chdir(repo)
    project = find_project([("tbp_m.core:M", "tbp-m")], HEAD_ROOT)
    assert [(p.name, p.folder) for p in project.packages] == [("tbp_m", "src")]

    code, said = export_project(project, flat, tmp_path / "flat", HEAD_ROOT)
    assert code.packages["tbp_m"] == tmp_path / "flat" and code.path == (tmp_path / "flat", HEAD_ROOT)
    assert (tmp_path / "flat" / "tbp_m" / "__init__.py").read_text() == "VERSION = 1\n"
    assert said.startswith("tbp-m 1.0 (tbp_m in the top/)") and "(the same on both sides)" in said
    # REF's entry points, beside REF's package: they hide HEAD's installed metadata from REF's processes
    info = tmp_path / "flat" / "tbp_m-1.0.dist-info"
    assert (info / "entry_points.txt").read_text() == "[tissuebench.methods]\ntbp_m = tbp_m.core:M\n"
    assert "Name: tbp-m\nVersion: 1.0" in (info / "METADATA").read_text()

    code, said = export_project(project, cfg, tmp_path / "cfg", HEAD_ROOT)
    assert code.packages["tbp_m"] == tmp_path / "cfg" / "lib" and said.startswith("tbp-m 2.0 (tbp_m in lib/)")
    assert (tmp_path / "cfg" / "lib" / "tbp_m-2.0.dist-info" / "entry_points.txt").is_file()

    code, said = export_project(project, none, tmp_path / "none", HEAD_ROOT)
    assert code.packages["tbp_m"] is None and said.startswith("no package tbp_m")
    head = git(repo, "rev-parse", "HEAD")
    code, said = export_project(project, head, tmp_path / "head", HEAD_ROOT)  # a dynamic version: __version__
    assert code.packages["tbp_m"] == tmp_path / "head" / "src" and said.startswith("tbp-m 3.0.dev (tbp_m in src/)")


def test_a_non_editable_install_is_found_in_the_repository_by_its_packaging(tmp_path, importable, monkeypatch):
    """An installed copy (site-packages) of the working directory's package: the repository's
    config that declares its distribution says where its source is, in a sub-folder too."""
    repo = init(tmp_path / "mono")
    sha = commit(repo, {"packages/tbp_n/pyproject.toml": _pyproject("tbp_N", "0.4", where="src"),
                        "packages/tbp_n/src/tbp_n/__init__.py": "", "pyproject.toml": _pyproject("other")})
    site = tmp_path / "site-packages"
    (site / "tbp_n").mkdir(parents=True)
    (site / "tbp_n" / "__init__.py").write_text("")
    importable(site)
    monkeypatch.chdir(repo / "packages")
    project = find_project([("tbp_n.x:N", "tbp-n")], HEAD_ROOT)
    assert project.how == "the working directory's repository"
    [package] = project.packages
    assert package.folder == "packages/tbp_n/src" and package.imported == site
    code, said = export_project(project, sha, tmp_path / "ref", HEAD_ROOT)
    assert code.packages["tbp_n"] == tmp_path / "ref" / "packages/tbp_n/src"
    assert said.startswith("tbp-n 0.4 (tbp_n in packages/tbp_n/src/)")


def test_a_module_served_from_elsewhere_is_not_that_sides_code(tmp_path):
    code = Code((tmp_path / "ref",), {"tissuebench": tmp_path / "ref", "tbp": tmp_path / "ref", "gone": None})
    files = {"tissuebench": str(tmp_path / "ref" / "tissuebench" / "__init__.py"),
             "tbp": str(tmp_path / "ref" / "tbp" / "__init__.py"), "tbp.new": str(tmp_path / "head" / "tbp" / "new.py"),
             "gone.m": str(tmp_path / "head" / "gone" / "m.py"), "numpy": "/anywhere/numpy/__init__.py",
             "tbp.ns": None}
    assert foreign(files, code) == {
        "gone": f"gone.m comes from {tmp_path / 'head' / 'gone' / 'm.py'}, and this side has no package gone",
        "tbp": f"tbp.new comes from {tmp_path / 'head' / 'tbp' / 'new.py'}, not from {tmp_path / 'ref' / 'tbp'}"}


def test_refs_processes_run_refs_plugin_or_leave_its_methods_out_saying_why(tmp_path, importable, monkeypatch):
    """REF's processes resolve the spec's plugin method to REF's copy (REF's export first on
    PYTHONPATH); a package REF lacks is imported from HEAD's copy there: its methods are left out
    of REF's sweep, saying so, instead of timing HEAD's code as REF's."""
    repo = init(tmp_path / "repo")
    base = commit(repo, {"pyproject.toml": _pyproject("tbp-r", where="src"), "src/tbp_r/__init__.py": "",
                         "src/tbp_r/m.py": PLUGIN.format(cls="R", name="tbp_r")})
    commit(repo, {"src/tbp_r/m.py": PLUGIN.format(cls="R", name="tbp_r") + "# HEAD\n"})
    importable(repo / "src")  # HEAD's copy, on PYTHONPATH too: where REF's processes would find it
    monkeypatch.chdir(repo)
    project = find_project([("tbp_r.m:R", "tbp-r")], HEAD_ROOT)
    code, _ = export_project(project, base, tmp_path / "ref", HEAD_ROOT)
    assert _methods_of(code, {"tbp_r.m:R", "nearest"}) == {}
    lacking = Code((tmp_path / "empty", HEAD_ROOT), {**code.packages, "tbp_r": None})  # REF without the package
    spec = '[[case]]\nname = "cornea_pinch"\n[[method]]\nname = "tbp_r.m:R"\n[[method]]\nname = "tbp_none:X"\n'
    ran, why = run_ref_sweep(lacking, spec, "ci", ["cornea_pinch"], tmp_path / "ref-sweep", log=lambda m: None)
    assert not ran and why == (
        "REF cannot run any method of the spec: tbp_none:X (unknown to REF's code); tbp_r.m:R (not REF's code: tbp_r "
        f"comes from {repo / 'src' / 'tbp_r' / '__init__.py'}, and this side has no package tbp_r)")
    assert not (tmp_path / "ref-sweep").exists()  # nothing run
