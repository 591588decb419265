"""``tissuebench fit SCENE --require "rate>=1kHz, error<=2%"``: train to a requirement.

A harness over the sweep's own pieces, not a second harness: every measurement of a fit is a
unit of a sweep spec (:mod:`.specs`) run by :func:`~tissuebench.studies.sweep.run_sweep` on the
sweep's executors, its references in the reference cache, its results in a results store; what
the fit adds is the greedy of reduced-basis practice (pyMOR's ``rb_greedy``, RBniCS) across
method families:

* :mod:`.target`      the requirement as numbers, and the stopping rule;
* :mod:`.specs`       the scene's generated spec, one case per family, written round by round;
* :mod:`.axes`        the parameter references are added along (the contract, a path's load
                      factor, a motion's amplitude);
* :mod:`.candidates`  where a reference may be added (never where the evaluation measures);
* :mod:`.indicator`   the cheap error indicator: the full model's residual at the reduced state;
* :mod:`.loop`        the rounds: measure, rank the candidates, add the worst, grow the model
                      where training no longer helps;
* :mod:`.manifest`    ``OUT/fit.json``, written atomically: a killed fit resumes;
* :mod:`.answer`      the cheapest unit that meets the requirement, its spec, the dense check
                      and the report (or why none can, and where the curves are heading).
"""
from .loop import FitSettings, run_fit
from .target import Clause, Target

__all__ = ["FitSettings", "run_fit", "Clause", "Target"]
