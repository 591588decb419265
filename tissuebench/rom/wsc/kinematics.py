"""Time-stepping kinematics of the reduced dynamics.

A scheme is written ``a1 = c_m (u1 - u~)``, ``v1 = v(u1)`` (backward Euler: ``v1 = (u1 -
u0)/dt``, ``a1 = (v1 - v0)/dt``; Newmark (beta, gamma); HHT-alpha with Hilber's weights), so
one step is the minimisation of an incremental potential (:mod:`.stepper`). The solves
with the step matrix are :mod:`.linsolve`.
"""
from __future__ import annotations

from dataclasses import dataclass

__all__ = ["SCHEMES", "Scheme", "make_scheme"]

@dataclass(frozen=True)
class Scheme:
    """Kinematics ``a1 = c_m (u1 - u~)``, ``v1 = v(u1)`` of an implicit scheme."""

    name: str
    beta: float = 0.25
    gamma: float = 0.5
    alpha: float = 0.0

    def c_m(self, dt):
        return 1.0 / (dt * dt) if self.name == "backward_euler" else 1.0 / (self.beta * dt * dt)

    def predicted(self, dt, u0, v0, a0):
        """``u~``: the u1 at which a1 = 0."""
        if self.name == "backward_euler":
            return u0 + dt * v0
        return u0 + dt * v0 + dt * dt * (0.5 - self.beta) * a0

    def kinematics(self, dt, u1, u0, v0, a0):
        """(v1, a1) from u1 and the state at t_n."""
        if self.name == "backward_euler":
            v1 = (u1 - u0) / dt
            return v1, (v1 - v0) / dt
        a1 = self.c_m(dt) * (u1 - self.predicted(dt, u0, v0, a0))
        return v0 + dt * ((1.0 - self.gamma) * a0 + self.gamma * a1), a1


def make_scheme(name: str, alpha: float = -0.05) -> Scheme:
    if name == "backward_euler":
        return Scheme("backward_euler", 1.0, 1.0, 0.0)
    if name == "newmark":
        return Scheme("newmark")
    if name == "hht":
        if not -1.0 / 3.0 <= alpha <= 0.0:
            raise ValueError(f"alpha must lie in [-1/3, 0], got {alpha!r}")
        return Scheme("hht", (1.0 - alpha) ** 2 / 4.0, 0.5 - alpha, alpha)
    raise ValueError(f"integrator = {name!r}: expected one of {SCHEMES}")


SCHEMES = ("backward_euler", "newmark", "hht")
