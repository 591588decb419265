"""The h/2 run's memory estimate (:mod:`tissuebench.reference.memory`): the peak probe against a
known allocation, the scaling of the two measured parts, and the text."""
from __future__ import annotations

import sys

import numpy as np
import pytest

from tissuebench.reference import memory
from tissuebench.reference.memory import FILL_EXPONENT, PeakProbe, RefinedMemory, size_text

linux = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the peak is reset through /proc/self")


@linux
def test_the_probe_sees_an_allocation_freed_before_it_ends_and_not_one_made_before_it():
    before = np.ones(40_000_000)  # 320 MB, resident before the probe: not its rise
    with PeakProbe() as probe:
        a = np.ones(25_000_000)  # 200 MB, touched, then freed inside
        del a
    assert 190e6 < probe.rise < 260e6
    with PeakProbe() as quiet:
        np.zeros(10)
    assert quiet.rise < 20e6
    del before


def test_the_estimate_scales_assembly_by_the_cells_and_the_factor_by_the_fill(monkeypatch):
    rises = iter([100e6, 50e6])

    class FixedProbe:
        def __enter__(self):
            self.rise = next(rises)
            return self

        def __exit__(self, *exc):
            return False

    class Backend:
        class problem:
            ndof = 300
            free_dofs = np.arange(270)

        @staticmethod
        def tangent(u):
            import scipy.sparse as sp

            return sp.identity(len(u), format="csr") * 2.0

    monkeypatch.setattr(memory, "PeakProbe", FixedProbe)
    est = memory.estimate_refined_peak(Backend(), 8 * 270)
    assert est.dofs_h == 270 and est.dofs_h_half == 2160
    assert est.peak == int(8 * 100e6 + 8 ** FILL_EXPONENT * 50e6)  # 0.8 GB + 16 x 50 MB
    assert est.text() == ("h/2 estimated at 1.6 GB (at h: assembly 100 MB x 8 cells, factorisation 50 MB x "
                          "(2160/270 unknowns)^(4/3))")


def test_no_estimate_where_the_peak_cannot_be_measured(monkeypatch):
    monkeypatch.setattr(memory, "_CLEAR", memory.Path("/nonexistent/clear_refs"))
    with PeakProbe() as probe:
        pass
    assert probe.rise is None
    none = RefinedMemory(None, None, None, 10, 80, 0.0, why="cannot be measured here")
    assert none.text() == "memory of the h/2 run not estimated: cannot be measured here"


@pytest.mark.parametrize("n, text", [(2.24e9, "2.24 GB"), (45.4e6, "45.4 MB"), (12e3, "12 kB"), (999, "999 B"),
                                     (1e9, "1 GB")])
def test_size_text_and_the_reports_sizes_are_one_formatting(n, text):
    from tissuebench.reports.format import nbytes

    assert size_text(n) == text and nbytes(n) == text
    assert nbytes(-1) == "-" and nbytes(float("nan")) == "-"  # the schema's missing value
