"""Moved to :mod:`tissuebench.gate.sides` (issue 55: the regression gate is one package, :mod:`tissuebench.gate`);
this path works for one release, with a DeprecationWarning."""
from .._moved import moved

__getattr__ = moved(__name__, "tissuebench.gate.sides")
