"""Exit-type exceptions: raised by a method's code, or sent by the user.

A plugin method is code tissuebench did not write (:mod:`.rom.plugins`). Its import, build, step,
reconstruction or outputs may raise :class:`SystemExit` (a ``sys.exit`` left in a script) or
:class:`KeyboardInterrupt`, which an ``except Exception`` lets through: one plugin would then end
``tissuebench methods`` or a whole sweep. Such an exception raised *by the code* fails that plugin
or that unit and the rest goes on; a real Ctrl-C (SIGINT delivered to the process) still stops the
sweep, cleanly and resumably. Python raises the same :class:`KeyboardInterrupt` for both, so:

* :func:`user_signals` (the CLI around every command, :func:`~tissuebench.studies.sweep.run_sweep`
  around a sweep, an executor's worker around a unit) installs a SIGINT handler that records
  that the signal arrived before it raises :class:`KeyboardInterrupt`, as Python's own does;
  with ``terminate=True`` also a SIGTERM handler (``timeout``, a batch system's stop) raising
  :class:`Terminated`, a :class:`KeyboardInterrupt`, so a sweep stops as on Ctrl-C (the manifest
  says "interrupted", the lock is released) and the CLI exits 128 + 15;
* :func:`raised_by_code` tells the two apart: a :class:`SystemExit` inside a unit or an import
  is always the code's (the user's own ``sys.exit`` never runs there); a
  :class:`KeyboardInterrupt` is the code's when no signal was recorded, or when it was raised
  in a thread other than the main one (Python delivers signals to the main thread only: a dask
  worker's unit runs in a thread), or while SIGINT is ignored (a background job of a script:
  no signal can raise it). Where nothing watches (a library call outside the CLI, a sweep and
  ``tissuebench.testing``), it cannot be told and counts as the user's: a real Ctrl-C is never
  swallowed.

Handlers are only installed in the main thread; a SIGINT handler of Python's or of an
embedding application is wrapped (recorded, then called), an ignored SIGINT is left ignored,
SIGTERM is only taken over from its default; all are restored on leaving.
"""
from __future__ import annotations

import signal
import threading
from contextlib import contextmanager

__all__ = ["Terminated", "user_signals", "raised_by_code", "stops", "exit_text", "EXIT_TYPES"]

#: the exceptions ``except Exception`` lets through that a method's code may raise
EXIT_TYPES = (SystemExit, KeyboardInterrupt)


class Terminated(KeyboardInterrupt):
    """SIGTERM arrived while :func:`user_signals` (``terminate=True``) watched: handled as Ctrl-C
    is; ``signum`` gives the command's exit status, 128 + 15."""

    signum = int(signal.SIGTERM)


_signalled: int | None = None  # the signal the recorder saw (None: none since it was installed)
_depth = 0  # nested user_signals in the main thread (0: nothing watches)
_chained = None  # the SIGINT handler the recorder replaced, called after recording (Python's raises)


def _on_sigint(signum, frame):
    global _signalled
    _signalled = signum
    if callable(_chained) and _chained is not _on_sigint:
        return _chained(signum, frame)
    raise KeyboardInterrupt


def _on_sigterm(signum, frame):
    global _signalled
    _signalled = signum
    raise Terminated


@contextmanager
def user_signals(terminate: bool = False):
    """Record the SIGINT (and with ``terminate`` the SIGTERM) the process receives meanwhile
    (module docstring); nested uses keep the outer record. A no-op outside the main thread.

    A Python SIGINT handler (Python's own, which raises :class:`KeyboardInterrupt`, or an
    embedding application's) is wrapped: the signal is recorded, then that handler runs. With
    SIGINT ignored or at its system default (a background job of a script), no signal can raise
    :class:`KeyboardInterrupt`, so every one seen meanwhile is the code's; the disposition is
    left as it is.
    """
    global _signalled, _depth, _chained
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    restore = []
    outer = _depth == 0
    try:
        if outer:
            _signalled = None
            previous = signal.getsignal(signal.SIGINT)
            if callable(previous) and previous is not _on_sigint:
                _chained = previous
                restore.append((signal.SIGINT, signal.signal(signal.SIGINT, _on_sigint)))
        if terminate and signal.getsignal(signal.SIGTERM) == signal.SIG_DFL:
            restore.append((signal.SIGTERM, signal.signal(signal.SIGTERM, _on_sigterm)))
        _depth += 1
        yield
    finally:
        _depth -= 1
        for signum, previous in reversed(restore):
            signal.signal(signum, previous)
        if outer:
            _chained = None


def raised_by_code(exc: BaseException) -> bool:
    """True when ``exc`` (a :data:`EXIT_TYPES` exception caught around a method's code) was raised
    by that code, False when it is the user's signal (module docstring)."""
    if isinstance(exc, SystemExit):
        return True
    if not isinstance(exc, KeyboardInterrupt):
        return False
    if threading.current_thread() is not threading.main_thread():
        return True
    return _depth > 0 and _signalled is None


def stops(exc: BaseException) -> bool:
    """Whether ``exc``, caught around a method's code, must go on up instead of failing that code's
    unit, plugin or check: the user's signal (:func:`raised_by_code` False), and any
    ``BaseException`` that is neither an ``Exception`` nor one of :data:`EXIT_TYPES` (a test
    runner's own exit or skip, ``GeneratorExit``)."""
    if isinstance(exc, EXIT_TYPES):
        return not raised_by_code(exc)
    return not isinstance(exc, Exception)


def exit_text(exc: BaseException, whose: str = "the method's code") -> str:
    """``"SystemExit(7) raised by the method's code"``: the exception as written, and by what."""
    shown = repr(exc)
    return f"{shown if len(shown) <= 120 else shown[:117] + '...'} raised by {whose}"
