"""A reference solve's progress as plain lines: what is solved, and how each load increment went.

:func:`~.runner.progress_bar` draws a bar for a terminal; a long check (``tissuebench verify
--convergence``: two meshes, minutes to hours) is also read in a log, where a bar is one line
rewritten and says neither how Newton is doing nor which mesh it is on. :class:`SolveLines` is
the ``progress`` callable of :func:`~.runner.solve` that writes one line per load increment
(load factor, Newton iterations, final residual, converged or not; the Newton solver reports
each attempt through its ``increment`` method), one per load step of a linear static run, and
one per twentieth of the end time of a dynamic run (a line per time step would bury the log).
"""
from __future__ import annotations

import math
import time

__all__ = ["SolveLines"]


class SolveLines:
    """``progress(done, total)`` of a reference run that writes lines through ``say``.

    Parameters
    ----------
    say : callable
        ``say(text)``, e.g. a print to stderr.
    prefix : str
        Put before every line: which run it is (``convergence dome h/2``).
    analysis : {"static", "dynamic"}
        What ``done`` and ``total`` count: the load factor, or the time.
    time_unit : str
        The unit of time of a dynamic run.
    forward : callable, optional
        Another ``progress(done, total)`` called with every report (a bar beside the lines).
    every : float
        Dynamics: a line each time the time reached passes another ``every`` of the end time.
    """

    def __init__(self, say, prefix: str, analysis: str = "static", time_unit: str = "s", forward=None,
                 every: float = 0.05):
        self.say, self.prefix, self.analysis, self.time_unit = say, prefix, analysis, time_unit
        self.forward, self.every = forward, every
        self.increments = 0  # attempted load increments (Newton) or load steps (linear) reported
        self._newton = False  # the solver reports each increment: a line per load factor would repeat it
        self._next = every
        self._t0 = time.perf_counter()

    def increment(self, inc, target) -> None:
        """One attempted Newton increment (:class:`~tissuebench.refsolvers.newton.Increment`)."""
        self._newton = True
        self.increments += 1
        res = inc.residual_norms[-1] if inc.residual_norms else math.nan
        # the absolute residual is in the scene's force unit; relative to the load it compares across scenes
        rel = f" (relative {res / inc.force_scale:.2g})" if inc.force_scale > 0 and math.isfinite(res) else ""
        how = "converged" if inc.converged else f"not converged: {inc.message or 'no reason given'}"
        self.say(f"{self.prefix}: increment {self.increments}: load factor {inc.load_factor:.6g}/{target:.6g}, "
                 f"{inc.iterations} Newton iteration{'' if inc.iterations == 1 else 's'}, residual {res:.3g}{rel}, "
                 f"{how} ({inc.wall_s:.3g} s)")

    def __call__(self, done, total) -> None:
        if self.forward is not None:
            self.forward(done, total)
        done, total = float(done), float(total)
        if self.analysis == "dynamic":
            frac = done / total if total > 0 else 1.0
            if frac + 1e-12 < self._next and frac < 1.0:
                return
            while self._next <= frac + 1e-12:
                self._next += self.every
            self.say(f"{self.prefix}: t {done:.4g}/{total:.4g} {self.time_unit} ({min(frac, 1.0):.0%}, "
                     f"{time.perf_counter() - self._t0:.3g} s)")
        elif not self._newton:  # a linear static run: one solve per load step
            self.increments += 1
            self.say(f"{self.prefix}: load step {self.increments}: load factor {done:.6g}/{total:.6g} "
                     f"({time.perf_counter() - self._t0:.3g} s)")
