"""The memory a refined mesh's solve will take, estimated before it runs.

The h/2 run of the convergence check has about 7 times the unknowns of the scene's mesh, and a
sparse factorisation of a 3D mesh's stiffness grows faster than its unknowns: nested dissection
fills ``O(n^(4/3))`` entries. A check that does not fit in the machine's memory would find out
hours in, by being killed. :func:`estimate_refined_peak` measures on the scene's own mesh (h) the
two parts of a Newton iteration's memory, with the formulation the refined run will use:

* the **assembly** of one tangent (element matrices and the triplets they are summed from),
  which grows with the cells: 8 times at h/2 (each tetrahedron split in eight);
* the **factorisation** of its free block, by the direct solver the refined run will factorise
  with (:func:`~tissuebench.refsolvers.linear_solvers.direct_solver_for` its unknowns: MKL
  PARDISO where it is installed), which grows as ``(n_h/2 / n_h)^(4/3)`` (:data:`FILL_EXPONENT`).

The estimate is their sum above the process's resident memory when the refined run starts. Each
part is the rise of the process's peak resident set (Linux ``VmHWM``, reset through
``/proc/self/clear_refs``) while it runs, after the memory the process has freed is given back to
the system (glibc's ``malloc_trim``: without it a part reuses pages the process still holds and
reads low, by a third on the organ below); where the peak cannot be reset (not Linux) the probe
reports that and no estimate is made. Measured on the 5k-node organ (nu = 0.499, h/2 107 805
dofs): see ``docs/explanation/nearly-incompressible.md``.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import gc
import re
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import psutil

from ..refsolvers.linear_solvers import direct_solver_for

__all__ = ["FILL_EXPONENT", "MEMORY_MARGIN", "PeakProbe", "RefinedMemory", "estimate_refined_peak", "available_bytes",
           "size_text"]

#: growth of a nested-dissection factor's entries with the unknowns of a 3D mesh
FILL_EXPONENT = 4.0 / 3.0
#: a refinement is refused when this times its estimate exceeds the memory it may use: on the 5k-node
#: organ the estimate was 0.95-1.01x (P1) and 0.97-1.00x (ANP) of the h/2 run's measured peak rise
MEMORY_MARGIN = 1.25
_STATUS, _CLEAR = Path("/proc/self/status"), Path("/proc/self/clear_refs")


def size_text(n_bytes: float) -> str:
    """``n_bytes`` for a person: "2.24 GB", "45.4 MB", "12 kB"."""
    for unit, size in (("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if abs(n_bytes) >= size:
            return f"{n_bytes / size:.3g} {unit}"
    return f"{n_bytes:.0f} B"


def available_bytes() -> int:
    """Memory the machine can give a process now without swapping, bytes (psutil's ``available``)."""
    return int(psutil.virtual_memory().available)


def _release_freed_memory() -> None:
    """Give memory the process has freed back to the system (glibc's ``malloc_trim``), so that what
    a probe allocates next raises the resident set instead of reusing pages it already holds."""
    gc.collect()
    name = ctypes.util.find_library("c")
    try:
        ctypes.CDLL(name).malloc_trim(0)
    except (OSError, AttributeError, TypeError):  # not glibc: the probe may then read low
        pass


def _peak_rss() -> int | None:
    try:
        match = re.search(r"VmHWM:\s+(\d+)\s+kB", _STATUS.read_text())
    except OSError:
        return None
    return int(match.group(1)) * 1024 if match else None


class PeakProbe:
    """``with PeakProbe() as p: ...`` then ``p.rise``: how far the process's peak resident set rose
    above its resident set at entry, bytes (None where the peak cannot be reset)."""

    def __enter__(self):
        _release_freed_memory()
        try:
            _CLEAR.write_text("5")  # resets VmHWM to the current resident set (Linux >= 4.0)
            self._reset = True
        except OSError:
            self._reset = False
        self._start = psutil.Process().memory_info().rss
        self.rise = None
        return self

    def __exit__(self, *exc):
        peak = _peak_rss() if self._reset else None
        self.rise = None if peak is None else max(0, peak - self._start)
        return False


@dataclass(frozen=True)
class RefinedMemory:
    """The estimate of :func:`estimate_refined_peak`: ``peak`` (bytes the refined run will take above
    the process's resident memory now, None when not measurable), its two measured parts at h
    (``assembly_h``, ``factor_h``, bytes), the unknowns ``dofs_h`` and ``dofs_h_half`` of the free
    blocks, the probe's wall time ``wall_s`` and ``why`` (when no estimate could be made)."""

    peak: int | None
    assembly_h: int | None
    factor_h: int | None
    dofs_h: int
    dofs_h_half: int
    wall_s: float
    why: str = ""

    def text(self) -> str:
        if self.peak is None:
            return f"memory of the h/2 run not estimated: {self.why}"
        return (f"h/2 estimated at {size_text(self.peak)} (at h: assembly {size_text(self.assembly_h)} x 8 cells, "
                f"factorisation {size_text(self.factor_h)} x ({self.dofs_h_half}/{self.dofs_h} unknowns)^(4/3))")


def estimate_refined_peak(backend, dofs_h_half: int) -> RefinedMemory:
    """Assemble the tangent at rest with ``backend`` (the scene's mesh, h, in the formulation the
    refined run will use) and factorise its free block, each under a :class:`PeakProbe`; scale the
    two rises to the refined mesh of ``dofs_h_half`` free unknowns (module docstring)."""
    pb = backend.problem
    free = pb.free_dofs
    t0 = time.perf_counter()
    with PeakProbe() as assembly:
        K_ff = backend.tangent(np.zeros(pb.ndof))[free][:, free]
    solver = direct_solver_for(int(dofs_h_half))
    with PeakProbe() as factor:
        solver.solve(K_ff, np.ones(K_ff.shape[0]))
    solver.reset()
    wall = time.perf_counter() - t0
    n_h = int(len(free))
    if assembly.rise is None or factor.rise is None:
        return RefinedMemory(None, None, None, n_h, int(dofs_h_half), wall,
                             why="the process's peak memory cannot be measured here (Linux /proc/self)")
    scale = (dofs_h_half / max(n_h, 1)) ** FILL_EXPONENT
    peak = int(8 * assembly.rise + scale * factor.rise)
    return RefinedMemory(peak, assembly.rise, factor.rise, n_h, int(dofs_h_half), wall)
