"""Module-level unit functions for the executor tests (spawned workers import them by name)."""
from __future__ import annotations

import os
import signal
import time

from tissuebench.studies.units import UnitOutcome


def sleepy(unit) -> UnitOutcome:
    """Sleep ``options["sleep"]`` seconds and return an ok row; ``options["die"]`` SIGKILLs the
    worker process running it (as the out-of-memory killer would)."""
    if unit.options.get("die"):
        os.kill(os.getpid(), signal.SIGKILL)
    time.sleep(unit.options.get("sleep", 0.0))
    return UnitOutcome({"unit_key": unit.key, "unit_status": "ok", "message": f"pid {os.getpid()}"})
