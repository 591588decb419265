"""The row's BLAS (studies/protocol.py::blas_info) is the one NumPy calls, whatever else the process
loaded: MKL comes in with PARDISO's factorisations (refsolvers/pardiso.py), and a sweep's rows must
not depend on whether a large reference was solved in the same process before them."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from tissuebench.refsolvers import pardiso
from tissuebench.studies import protocol


def test_mkl_loaded_for_pardiso_does_not_change_the_rows_blas(monkeypatch):
    before = protocol.blas_info()
    if pardiso.why_no_pardiso():
        pytest.skip(pardiso.why_no_pardiso())
    K = sp.diags([-np.ones(99), 4 * np.ones(100), -np.ones(99)], [-1, 0, 1]).tocsr()
    pardiso.PardisoSolver().solve(K, np.ones(100))  # libmkl_rt is in the process from here on
    assert protocol.blas_info() == before
    assert before["blas"] == protocol._numpy_blas_api() and before["blas_threads"] >= 1
    # the other side: without NumPy's BLAS name, every BLAS loaded counts (MKL among them)
    monkeypatch.setattr(protocol, "_numpy_blas_api", lambda: None)
    assert "mkl" in protocol.blas_info()["blas"].split(",")
