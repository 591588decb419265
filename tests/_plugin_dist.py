"""Installed plugin distributions for the tests, without pip: a ``NAME-VERSION.dist-info`` folder
(METADATA, entry_points.txt, top_level.txt) and its modules written into a folder that goes on
``sys.path`` and ``PYTHONPATH``, which is all :mod:`importlib.metadata` reads (the real entry-point
discovery, in this process and in every process it starts)."""
from __future__ import annotations

import fnmatch
import importlib
import os
import sys
from pathlib import Path

from tissuebench.rom import METHODS
from tissuebench.rom.plugins import FAILURES, PLUGINS, _distribution_of_top, _files_hash, load_entry_points

#: a plugin method: the last snapshot of a path scaled by the load factor (exact for a linear
#: scene, flagged outside the training's load factors); ``NAME`` is replaced by the method's name
TOY = '''
import numpy as np

from tissuebench.rom import LinearReconstruction, OnlineModel, RomMethod, StepResult, check_parameters
from tissuebench.rom.base import Applies


class _Model(LinearReconstruction, OnlineModel):
    kind = "map"

    def __init__(self, training, gain):
        self.name, self.ndof = "NAME", training.snapshots.shape[0]
        self.free_dofs = training.free_dofs
        self.problem = training.backend.problem
        lams = training.parameter_values("load_factor")
        j = int(np.argmax(lams))
        self.basis = training.snapshots[self.free_dofs, j:j + 1] / lams[j]
        self.top, self.gain = float(lams[j]), gain

    @property
    def n_reduced(self):
        return 1

    def step(self, mu):
        mu = check_parameters(mu, ("load_factor",), self.name)
        lam = mu["load_factor"]
        if not 0.0 <= lam <= self.top:
            return StepResult(np.array([self.gain * lam]), "extrapolation", f"load_factor {lam} outside [0, "
                              f"{self.top}]", mu=mu)
        return StepResult(np.array([self.gain * lam]), mu=mu)


class Toy(RomMethod):
    """The last snapshot scaled by the load factor."""

    name = "NAME"
    kind = "map"
    training_kinds = ("path",)
    applies = Applies(dead_loads=True, homogeneous_dirichlet=True)

    def __init__(self, gain: float = 1.0):
        self.gain = float(gain)

    def build(self, training):
        return _Model(training, self.gain)
'''


def toy_source(name: str) -> str:
    return TOY.replace("NAME", name)


def write_dist(root: Path, dist: str, version: str, entry_points: dict, modules: dict, top_level=None) -> Path:
    """``root/<dist>-<version>.dist-info`` declaring ``entry_points`` (name -> "module:Class") in
    group ``tissuebench.methods``, and ``modules`` (name -> source) as ``root/<name>.py``;
    ``top_level``: the import names the distribution ships (default: ``modules``'s)."""
    root.mkdir(parents=True, exist_ok=True)
    info = root / f"{dist.replace('-', '_')}-{version}.dist-info"
    info.mkdir()
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {dist}\nVersion: {version}\n")
    lines = ["[tissuebench.methods]"] + [f"{k} = {v}" for k, v in entry_points.items()]
    (info / "entry_points.txt").write_text("\n".join(lines) + "\n")
    (info / "top_level.txt").write_text("\n".join(top_level or modules) + "\n")
    for name, source in modules.items():
        (root / f"{name}.py").write_text(source)
    return root


def on_path(monkeypatch, folder) -> str:
    """``folder`` first on this process's ``sys.path`` and on the ``PYTHONPATH`` of every process it
    starts (where an install puts a package's import location), the import caches invalidated;
    ``monkeypatch`` undoes both. Returns the folder as a string."""
    folder = str(folder)
    monkeypatch.syspath_prepend(folder)
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join(p for p in (folder, os.environ.get("PYTHONPATH")) if p))
    importlib.invalidate_caches()
    return folder


def forget_modules(*tops: str) -> None:
    """Drop the packages whose top-level name matches one of ``tops`` (``fnmatch`` patterns:
    ``"podreg"``, ``"tbp_*"``) and their modules from ``sys.modules``: the next test imports its own
    copy of a package a test put on the path."""
    for name in [m for m in sys.modules if any(fnmatch.fnmatchcase(m.split(".")[0], top) for top in tops)]:
        del sys.modules[name]


class Installed:
    """A folder of plugin distributions on this process's path and ``PYTHONPATH`` (:func:`on_path`),
    the registry re-armed to read their entry points at its next read; :meth:`undo` forgets them."""

    def __init__(self, root: Path, monkeypatch):
        self.root = root
        on_path(monkeypatch, root)
        self.before = set(dict.keys(METHODS))
        _distribution_of_top.cache_clear()
        METHODS.arm(load_entry_points)

    def undo(self) -> None:
        for name in set(dict.keys(METHODS)) - self.before:
            dict.pop(METHODS, name)
            PLUGINS.pop(name, None)
        FAILURES.clear()
        _files_hash.cache_clear()
        _distribution_of_top.cache_clear()
        for mod in [m for m, v in sys.modules.items() if str(getattr(v, "__file__", "") or "").startswith(
                str(self.root))]:
            del sys.modules[mod]
