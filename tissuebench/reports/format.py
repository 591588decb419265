"""Number formatting shared by the report's tables and texts (units always printed)."""
from __future__ import annotations

import math

__all__ = ["hz", "seconds", "percent", "nbytes", "number", "times"]


def _finite(v) -> bool:
    try:
        return math.isfinite(float(v))
    except (TypeError, ValueError):
        return False


def hz(v) -> str:
    """A rate [Hz]: ``'512 Hz'``, ``'22.1 kHz'``."""
    if not _finite(v):
        return "-" if v is None or v != v else str(v)
    return f"{v / 1e3:.3g} kHz" if v >= 1e3 else f"{v:.3g} Hz"


def seconds(v) -> str:
    """A duration [s] in s, ms, µs or ns (3 significant digits)."""
    if not _finite(v):
        return "-" if v is None or v != v else str(v)
    for scale, unit in ((1.0, "s"), (1e-3, "ms"), (1e-6, "µs")):
        if abs(v) >= scale:
            return f"{v / scale:.3g} {unit}"
    return f"{v / 1e-9:.3g} ns"


def percent(v) -> str:
    """A relative value as percent; ``inf`` (a step that failed against a reference) said so."""
    if v is None or v != v:
        return "-"
    if v == math.inf:
        return "inf (failed step)"
    return f"{100 * v:.3g} %"


def nbytes(v) -> str:
    """A size [bytes] in kB / MB / GB (1000-based); ``-`` for the schema's missing value (-1)."""
    from ..reference.memory import size_text  # lazy: the reference layer's, one formatting of a size

    if not _finite(v) or v < 0:
        return "-"
    return size_text(v)


def number(v, digits: int = 4) -> str:
    if isinstance(v, bool) or not isinstance(v, (int, float)) and not hasattr(v, "__float__"):
        return str(v)
    if not _finite(v):
        return "-" if v != v else str(v)
    return f"{float(v):.{digits}g}"


def times(ratio) -> str:
    """How many times too small a headroom ratio is (``1 / ratio``), e.g. ``'1.6x'``."""
    if not _finite(ratio) or ratio <= 0:
        return "infinitely"
    return f"{1.0 / ratio:.3g}x"
