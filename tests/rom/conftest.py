"""Fixtures shared by the tests of the reduced models: the cut cornea and its PGD training, which
the cutting, SVK and rank-floor tests build on (module scope: each test module builds its own,
as before, and may not change it)."""
from __future__ import annotations

import pytest

from tissuebench.cases.scene import load
from tissuebench.rom.pgd import pgd_training


@pytest.fixture(scope="module")
def cornea_cut():
    """The cornea_cut scene at ci resolution (219 nodes; its ``[cut]`` incisions)."""
    return load("cornea_cut")


@pytest.fixture(scope="module")
def cornea_cut_pgd(cornea_cut):
    """Its PGD training (:func:`~tissuebench.rom.pgd.pgd_training`: the backend's operators and the
    point-load family of the anterior surface)."""
    return pgd_training(cornea_cut)
