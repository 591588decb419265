"""``ezyrb``: POD with interpolated coefficients, by EZyRB (optional: EZyRB pulls torch).

EZyRB (1.3, https://github.com/mathLab/EZyRB) builds the whole offline phase:
``ezyrb.Database`` of the training's load factors and snapshots (every dof: the prescribed values
come back with the modes, as ``pod_interp``'s), ``ezyrb.POD("svd", rank)``, and an approximation of
the reduced coefficients over the load factor, ``ezyrb.RBF`` (SciPy's ``RBFInterpolator``, kernel
``kernel``: the interpolant ``pod_interp interpolation = "rbf"`` uses, so the pair is a check of the
two wrappings) or ``ezyrb.GPR`` (scikit-learn's Gaussian process regression, its kernel's
hyperparameters fitted by maximum likelihood with ``restarts`` restarts). A step is one evaluation of
the fitted approximation (``ReducedOrderModel.approximation.predict``): the reduced coefficients; the
full field is ``POD.modes @ q``.

``import ezyrb`` imports torch (seconds); it happens at the build. Where EZyRB is not installed the
method says so (``tissuebench methods``) and applies nowhere.
"""
from __future__ import annotations

import time

import numpy as np
from tissuebench.rom import Applies, LinearReconstruction, OnlineModel, RomMethod, StepResult, Training, \
    check_parameters

from ._common import envelope_of, fraction, missing, positive_int, status_at

__all__ = ["Ezyrb"]

INTERPOLATION = ("rbf", "gpr")


class Ezyrb(RomMethod):
    """POD + RBF or GPR interpolation of the coefficients, by EZyRB (module docstring).

    Options
    -------
    n_modes : int or None
        POD rank (None: the smallest capturing ``energy``, EZyRB's float rank).
    energy : float in (0, 1]
        The energy criterion when ``n_modes`` is None (1: no truncation).
    interpolation : {"rbf", "gpr"}
        ``ezyrb.RBF`` or ``ezyrb.GPR``.
    kernel : str
        The RBF kernel (SciPy's names; ``"rbf"`` only).
    restarts : int
        GPR's optimiser restarts (``"gpr"`` only).
    """

    name = "ezyrb"
    kind = "map"
    training_kinds = ("path",)
    applies = Applies()
    counterpart = ("pod_interp", {})

    def __init__(self, n_modes=None, energy=0.999, interpolation="rbf", kernel="thin_plate_spline", restarts=5):
        who = "ezyrb"
        if interpolation not in INTERPOLATION:
            raise ValueError(f"{who} option interpolation = {interpolation!r}; valid: {list(INTERPOLATION)}")
        if not isinstance(kernel, str) or not kernel:
            raise ValueError(f"{who} option kernel = {kernel!r}: a SciPy RBFInterpolator kernel name")
        self.options = dict(n_modes=positive_int(who, "n_modes", n_modes, True), energy=fraction(who, "energy", energy),
                            interpolation=interpolation, kernel=kernel,
                            restarts=positive_int(who, "restarts", restarts))

    @classmethod
    def unavailable(cls) -> str:
        return missing("ezyrb")

    def build(self, training: Training) -> OnlineModel:
        if training.snapshots is None or not training.parameters:
            raise ValueError("ezyrb.build: needs snapshots and their load factors")
        tic = time.perf_counter()
        import ezyrb

        imported = time.perf_counter() - tic
        o = self.options
        lams = training.parameter_values("load_factor")
        db = ezyrb.Database(lams[:, None], training.snapshots.T)
        rank = o["n_modes"] if o["n_modes"] else (o["energy"] if o["energy"] < 1.0 else -1)
        approximation = ezyrb.RBF(kernel=o["kernel"]) if o["interpolation"] == "rbf" else \
            ezyrb.GPR(optimization_restart=o["restarts"])
        rom = ezyrb.ReducedOrderModel(db, ezyrb.POD("svd", rank=rank), approximation).fit()
        modes = np.ascontiguousarray(rom.reduction.modes)
        info = {"library": "ezyrb", "n_modes": int(modes.shape[1]), "interpolation": o["interpolation"],
                "import_s": imported, "offline_s": time.perf_counter() - tic}
        model = _EzyrbModel(self.name, rom.approximation, modes, envelope_of(training), info)
        if training.outputs:
            model.attach_outputs(training.outputs)
        return model


class _EzyrbModel(LinearReconstruction, OnlineModel):
    """A step: EZyRB's approximation of the reduced coefficients at the load factor."""

    kind = "map"

    def __init__(self, name, approximation, modes, envelope, info):
        self.name, self._approximation, self.basis = name, approximation, modes
        self.ndof = modes.shape[0]
        self.free_dofs = np.arange(self.ndof)  # every dof: the modes carry the prescribed values
        self._envelope, self.info = dict(envelope), info
        self._point = np.zeros((1, 1))

    @property
    def n_reduced(self) -> int:
        return self.basis.shape[1]

    @property
    def envelope(self) -> dict:
        return dict(self._envelope)

    def step(self, mu) -> StepResult:
        lam = float(check_parameters(mu, ("load_factor",), self.name)["load_factor"])
        self._point[0, 0] = lam
        q = np.asarray(self._approximation.predict(self._point), float).reshape(-1)
        if q.shape != (self.n_reduced,) or not np.all(np.isfinite(q)):
            return StepResult(None, "failed", f"{self.name}: EZyRB's approximation gave no finite coefficients at "
                              f"load factor {lam:g}", mu={"load_factor": lam})
        status, message = status_at(self.name, lam, self._envelope)
        return StepResult(q, status, message, mu={"load_factor": lam})

    def floor_ops(self):
        """One evaluation of EZyRB's approximation (the step's arithmetic) and the outputs' product."""
        point, approximation = np.full((1, 1), sum(self._envelope.get("load_factor", (0.0, 1.0))) / 2), \
            self._approximation
        return lambda: approximation.predict(point)
