"""Session-wide settings: one reference cache for the whole test session, so tests that need
the same reference run share it (the sweep harness's content-hashed cache), and nothing is
written to the user's cache folder."""
import os

import pytest


@pytest.fixture(scope="session", autouse=True)
def reference_cache(tmp_path_factory):
    path = tmp_path_factory.mktemp("reference-cache")
    old = os.environ.get("TISSUEBENCH_CACHE")
    os.environ["TISSUEBENCH_CACHE"] = str(path)
    yield path
    if old is None:
        os.environ.pop("TISSUEBENCH_CACHE", None)
    else:
        os.environ["TISSUEBENCH_CACHE"] = old
