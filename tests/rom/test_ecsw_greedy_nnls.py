"""ECSW's greedy NNLS (rom/galerkin/ecsw.py::greedy_nnls), warm-started on an updated QR, against
the version it replaces (SciPy's NNLS refitting the chosen columns from scratch at every step,
copied here as the reference) and against SciPy's NNLS of the whole problem; the two sides of its
stopping rule, its cap, the problems where nothing or a duplicate would enter, and its cost
counted in QR updates (no timing). The hand-worked cases: test_galerkin_numbers.py."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg
import scipy.optimize
from scipy.optimize import nnls

from tissuebench.rom.galerkin import ecsw
from tissuebench.rom.galerkin.ecsw import greedy_nnls

TOLS = (0.1, 0.03, 0.01, 3e-3, 1e-3, 0.0)


def _from_scratch(A, b, tol, max_elements):
    """The greedy NNLS before the warm start: ``nnls`` on the chosen columns at each step. Returns
    ``(columns, weights, relative residual, outer iterations)``."""
    bn = max(float(np.linalg.norm(b)), 1e-300)
    cols, w, r = np.zeros(0, dtype=np.int64), np.zeros(0), b.copy()
    iterations = 0
    for _ in range(3 * max_elements):
        if np.linalg.norm(r) <= tol * bn or len(cols) >= max_elements:
            break
        iterations += 1
        g = A.T @ r
        g[cols] = -np.inf
        j = int(np.argmax(g))
        if not g[j] > 0:
            break
        cols = np.append(cols, j)
        w, _ = nnls(A[:, cols], b, maxiter=50 * len(cols))
        cols, w = cols[w > 0], w[w > 0]
        r = b - A[:, cols] @ w
    return cols, w, float(np.linalg.norm(r) / bn), iterations


def _elements(seed, rows=300, columns=200, used=60, noise=0.01):
    """Non-negative columns like element contributions; b a sparse non-negative combination of
    them plus noise (so that the fit is never exact and its optimum unique)."""
    rng = np.random.default_rng(seed)
    A = rng.random((rows, columns)) ** 3
    w = np.zeros(columns)
    w[rng.choice(columns, used, replace=False)] = rng.random(used)
    b = A @ w
    return A, b + noise * np.linalg.norm(b) / rows ** 0.5 * rng.standard_normal(rows)


def _decoys(seed, rows=300):
    """b close to the sum of 10 of 40 columns, plus 10 decoys: large columns near positive
    combinations of those 10 that enter first and must leave again as the others come in."""
    rng = np.random.default_rng(seed)
    T = rng.random((rows, 40))
    decoys = [(T[:, :10] @ rng.random(10)) * (0.3 + 0.05 * k) + 0.3 * rng.random(rows) for k in range(10)]
    return np.column_stack([T, *decoys]), T[:, :10].sum(axis=1) + 0.02 * rng.standard_normal(rows)


def _same_fit(new, old):
    cols, w, res = new
    assert cols.dtype == np.int64 and np.all(w > 0) and len(set(cols.tolist())) == len(cols)
    assert set(cols.tolist()) == set(old[0].tolist())
    np.testing.assert_allclose(w[np.argsort(cols)], old[1][np.argsort(old[0])], rtol=1e-8)
    assert abs(res - old[2]) <= 1e-10


class _Counts:
    """qr_insert and qr_delete in ecsw's namespace wrapped to count (and record) their calls."""

    def __init__(self, monkeypatch):
        self.inserted, self.deletes = [], 0
        insert, delete = scipy.linalg.qr_insert, scipy.linalg.qr_delete

        def counted_insert(Q, R, u, k, *args, **kwargs):
            self.inserted.append(np.array(u, copy=True))
            return insert(Q, R, u, k, *args, **kwargs)

        def counted_delete(*args, **kwargs):
            self.deletes += 1
            return delete(*args, **kwargs)

        monkeypatch.setattr(ecsw, "qr_insert", counted_insert)
        monkeypatch.setattr(ecsw, "qr_delete", counted_delete)

    def reentries(self):
        """How many insertions were of a column inserted before."""
        seen = {u.tobytes() for u in self.inserted}
        return len(self.inserted) - len(seen)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_same_elements_and_weights_as_refitting_from_scratch(seed):
    A, b = _elements(seed)
    for tol in TOLS:
        _same_fit(greedy_nnls(A, b, tol, A.shape[1]), _from_scratch(A, b, tol, A.shape[1]))


@pytest.mark.parametrize("seed", [0, 1, 2, 27])
def test_elements_leave_as_the_fit_goes_and_the_result_is_unchanged(seed, monkeypatch):
    """On the decoy problems columns leave (qr_delete is called) and the fit is still the
    from-scratch one at every tolerance."""
    A, b = _decoys(seed)
    counts = _Counts(monkeypatch)
    for tol in (0.03, 0.02, 0.01, 0.0):
        _same_fit(greedy_nnls(A, b, tol, A.shape[1]), _from_scratch(A, b, tol, A.shape[1]))
    assert counts.deletes > 0


def test_a_column_that_left_reenters_within_the_iteration(monkeypatch):
    """Column 1 enters, leaves when 5 enters (its weight crosses zero on the way to the new
    least-squares weights), and has a positive correlation with the residual of {0, 5}: the
    iteration's NNLS optimum over {0, 1, 5} keeps it, as a refit from scratch does. At tol 0.7 that
    is the last iteration (without the re-entry the fit would stop at {0, 5})."""
    A = np.array([[0.35, 0.49, 0.31, 2.48, -1.72, 0.25],
                  [1.84, 1.23, -0.29, 1.26, -0.55, -1.22],
                  [-1.04, -1.92, 1.35, -1.66, 0.85, 1.07],
                  [-1.33, 1.61, -0.8, 0.23, -0.66, 0.52],
                  [0.46, -1.82, 0.49, 1.22, 1.19, -0.56]])
    b = np.array([1.52, -0.92, 0.14, -2.5, -1.56])
    counts = _Counts(monkeypatch)
    new = greedy_nnls(A, b, 0.7, 6)
    assert sorted(new[0].tolist()) == [0, 1, 5] and counts.reentries() == 1
    _same_fit(new, _from_scratch(A, b, 0.7, 6))
    np.testing.assert_allclose(new[1], nnls(A[:, new[0]], b)[0], rtol=1e-12)
    _same_fit(greedy_nnls(A, b, 0.0, 6), _from_scratch(A, b, 0.0, 6))


@pytest.mark.parametrize("problem", [_elements(3), _elements(4, rows=200, columns=150, used=100), _decoys(5)])
def test_tol_0_reaches_the_nnls_optimum(problem):
    A, b = problem
    cols, w, res = greedy_nnls(A, b, 0.0, A.shape[1])
    x, rnorm = nnls(A, b, maxiter=50 * A.shape[1])
    assert res == pytest.approx(rnorm / np.linalg.norm(b), rel=1e-9)
    assert set(cols.tolist()) == set(np.flatnonzero(x > 0).tolist())
    np.testing.assert_allclose(w[np.argsort(cols)], x[np.sort(cols)], rtol=1e-8)


def test_both_sides_of_the_tolerance():
    """At a tolerance just above a residual the fit reaches it stops there; just below it goes on."""
    A, b = _elements(6)
    cols, w, res = greedy_nnls(A, b, 0.01, A.shape[1])
    above = greedy_nnls(A, b, res * (1 + 1e-9), A.shape[1])
    assert above[0].tolist() == cols.tolist() and above[2] == res
    below = greedy_nnls(A, b, res * (1 - 1e-9), A.shape[1])
    assert len(below[0]) > len(cols) and below[2] <= res * (1 - 1e-9)
    _same_fit(below, _from_scratch(A, b, res * (1 - 1e-9), A.shape[1]))


def test_at_most_max_elements():
    A, b = _elements(7)
    for most in (1, 5, 17, 40):
        new = greedy_nnls(A, b, 0.0, most)
        assert len(new[0]) <= most
        _same_fit(new, _from_scratch(A, b, 0.0, most))
    assert len(greedy_nnls(A, b, 0.0, 0)[0]) == 0


def test_no_column_with_a_positive_correlation_enters_none():
    A, _ = _elements(8, rows=40, columns=30, used=10)
    for b in (-A @ np.ones(30), -np.ones(40)):  # every correlation negative
        cols, w, res = greedy_nnls(A, b, 0.0, 30)
        assert cols.dtype == np.int64 and cols.tolist() == [] and w.tolist() == [] and res == 1.0
    A = np.vstack([A, np.zeros((10, 30))])  # b orthogonal to every column: correlations 0
    b = np.concatenate([np.zeros(40), np.ones(10)])
    assert greedy_nnls(A, b, 0.0, 30)[0].tolist() == []


def test_a_duplicated_column_neither_loops_nor_enters_twice(monkeypatch):
    """Column 3 twice (as 3 and 30) and once more as a multiple (31): the copies are in the span of
    the columns in and cannot enter once 3 is in; the fit is that of the matrix without them."""
    A, b = _elements(9, rows=60, columns=30, used=20)
    A2 = np.column_stack([A, A[:, 3], 2 * A[:, 3]])
    counts = _Counts(monkeypatch)
    cols, w, res = greedy_nnls(A2, b, 0.0, 32)
    assert len(counts.inserted) <= 3 * 32
    assert len({3, 30, 31} & set(cols.tolist())) <= 1 and np.all(w > 0)
    assert res == pytest.approx(nnls(A, b)[1] / np.linalg.norm(b), rel=1e-9)
    # b the duplicated column itself: the multiple (the largest correlation) alone, weight 1/2
    cols, w, res = greedy_nnls(A2, A[:, 3].copy(), 0.0, 32)
    assert cols.tolist() == [31] and w == pytest.approx([0.5], rel=1e-12) and res < 1e-14


def test_more_columns_than_rows():
    """As many columns in as rows (a square QR) and more candidates: no crash, the NNLS optimum."""
    rng = np.random.default_rng(10)
    A = rng.standard_normal((6, 20))
    b = rng.standard_normal(6)
    cols, w, res = greedy_nnls(A, b, 0.0, 20)
    assert len(cols) <= 6 and np.all(w > 0)
    assert res <= nnls(A, b)[1] / np.linalg.norm(b) + 1e-12


def test_cost_is_qr_updates_and_no_nnls(monkeypatch):
    """Every column entering is one qr_insert (a column that left and re-enters, one more after its
    qr_delete): at most outer iterations + drops; no NNLS solve at all."""
    A, b = _decoys(27)
    expected = _from_scratch(A, b, 0.0, A.shape[1])

    def refused(*args, **kwargs):
        raise AssertionError("scipy.optimize.nnls called")

    monkeypatch.setattr(scipy.optimize, "nnls", refused)
    monkeypatch.setattr(scipy.optimize._nnls, "nnls", refused)
    monkeypatch.setattr(ecsw, "nnls", refused, raising=False)
    counts = _Counts(monkeypatch)
    new = greedy_nnls(A, b, 0.0, A.shape[1])
    _same_fit(new, expected[:3])
    assert counts.deletes > 0
    assert len(counts.inserted) <= expected[3] + counts.deletes
    assert len(counts.inserted) == len(new[0]) + counts.deletes  # no column refused on this problem
