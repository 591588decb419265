"""Session-wide settings.

One reference cache for the whole test session, so tests that need the same reference run
share it (the sweep harness's content-hashed cache): ``$TISSUEBENCH_CACHE`` when set (CI
sets it, so its later sweep steps reuse the references the tests computed), else a
temporary folder (nothing is written to the user's cache folder).
"""
import os

import pytest


@pytest.fixture(scope="session", autouse=True)
def reference_cache(tmp_path_factory):
    if os.environ.get("TISSUEBENCH_CACHE", "").strip():
        yield os.environ["TISSUEBENCH_CACHE"]
        return
    path = tmp_path_factory.mktemp("reference-cache")
    os.environ["TISSUEBENCH_CACHE"] = str(path)
    yield path
    os.environ.pop("TISSUEBENCH_CACHE", None)


# Property-based fuzzing (tests/studies/test_fuzz_inputs.py): seeded (derandomized) profiles, no
# example database. ``ci`` is the default; ``pytest --hypothesis-profile=fuzz`` runs 5x more.
from hypothesis import HealthCheck, settings  # noqa: E402

_FUZZ_COMMON = dict(derandomize=True, database=None, deadline=None, print_blob=True,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])
settings.register_profile("ci", max_examples=200, **_FUZZ_COMMON)
settings.register_profile("fuzz", max_examples=1000, **_FUZZ_COMMON)
settings.load_profile("ci")
