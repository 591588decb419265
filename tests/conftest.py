"""Session-wide settings.

One reference cache for the whole test session, so tests that need the same reference run
share it (the sweep harness's content-hashed cache): ``$TISSUEBENCH_CACHE`` when set (CI
sets it, so its later sweep steps reuse the references the tests computed), else a
temporary folder (nothing is written to the user's cache folder).

Under pytest-xdist, each worker's BLAS gets its share of the cores (cores // workers, at least
one), in the worker and in the processes its tests start: N workers each running a BLAS with
one thread per core oversubscribe the machine (2 workers x 2 threads on 2 cores; the slow
presets ran 8 % faster with one thread per worker, issue 29).
"""
import os

import pytest
from threadpoolctl import threadpool_limits

_BLAS_ENV = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def _blas_share() -> int | None:
    """Threads per xdist worker, or None outside xdist (or when the user set them)."""
    workers = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "0") or 0)
    if workers < 2 or any(os.environ.get(k) for k in _BLAS_ENV):
        return None
    return max(1, (os.cpu_count() or 1) // workers)


@pytest.fixture(scope="session", autouse=True)
def blas_share_per_worker():
    share = _blas_share()
    if share is None:
        yield None
        return
    for key in _BLAS_ENV:  # the sweeps, CLI runs and workers the tests start
        os.environ[key] = str(share)
    with threadpool_limits(limits=share):
        yield share
    for key in _BLAS_ENV:
        os.environ.pop(key, None)


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
