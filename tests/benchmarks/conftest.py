"""Benchmarks are timing runs, not verification: they are marked slow, so the default
``pytest`` (``-m "not slow"``) leaves them to ``.ci/run``'s second pass and ``tox -e bench``."""
import pytest


def pytest_collection_modifyitems(config, items):
    for item in items:
        if "benchmarks" in item.path.parts:
            item.add_marker(pytest.mark.slow)
