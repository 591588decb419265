"""L-BFGS on the incremental potential of one reduced step (:mod:`.stepper`).

Minimises ``Phi(z) = c_m/2 |z - z~|^2_M + (the rest)`` given an ``evaluate(z, Mdz)`` that
returns ``(Phi, gradient, extra)`` from ``z`` and ``M (z - z~)``. The product with ``M`` is
carried along instead of recomputed at every evaluation: a trial point ``z + s d`` has
``M (z + s d - z~) = Mdz + s M d``, so an iteration costs one product ``M d`` however many
line-search trials it takes, and a start point comes with its product from the caller
(known from the state for the explicit predictor: no product at all).

Initial inverse Hessian: ``precondition`` (the factorised step matrix at the start state).
Armijo backtracking. The (s, y) pairs are the caller's lists, so they may be kept from one
step to the next (``history = "run"`` of the stepper).
"""
from __future__ import annotations

import time

import numpy as np

__all__ = ["lbfgs", "two_loop"]


def two_loop(g, S, Y, precondition) -> np.ndarray:
    """The L-BFGS inverse-Hessian product ``B^-1 g`` from the pairs and the initial inverse."""
    q = np.array(g, dtype=float)
    alphas = []
    for s, y in zip(reversed(S), reversed(Y)):
        rho = 1.0 / (y @ s)
        a = rho * (s @ q)
        q -= a * y
        alphas.append((rho, a))
    r = precondition(q)
    for (s, y), (rho, a) in zip(zip(S, Y), reversed(alphas)):
        r += s * (a - rho * (y @ r))
    return r


def lbfgs(evaluate, starts, precondition, matvec_M, tol_of, max_iter, S, Y, memory):
    """Minimise from the first start point with a finite Phi.

    Parameters
    ----------
    evaluate : callable ``(z, Mdz) -> (phi, g, extra)``
    starts : sequence of ``(z, Mdz)``
        Tried in order (a start that inverts an element has a non-finite Phi).
    precondition : callable ``b -> H^-1 b``
    matvec_M : callable ``d -> M d``
    tol_of : callable ``|g(start)| -> tolerance``
    max_iter, memory : int
    S, Y : lists
        (s, y) pairs, updated in place (cleared on a restart).

    Returns
    -------
    ok, z, Mdz, extra, info : bool, array, array, object, dict
        ``info``: iterations, evaluations, residual, converged, solve_s, message on failure.
    """
    tic = time.perf_counter()
    evals = 0
    for z, Mdz in starts:
        phi, g, extra = evaluate(z, Mdz)
        evals += 1
        if np.isfinite(phi):
            break
    tol = tol_of(np.linalg.norm(g))
    for it in range(max_iter + 1):
        gn = float(np.linalg.norm(g))
        if not np.isfinite(phi) or not np.isfinite(gn):
            return False, z, Mdz, extra, {"message": f"non-finite energy or force (an inverted element?) at "
                                                     f"iteration {it}", "iterations": it, "evaluations": evals}
        if gn <= tol:
            return True, z, Mdz, extra, {"iterations": it, "evaluations": evals, "residual": gn, "converged": True,
                                         "solve_s": time.perf_counter() - tic}
        if it == max_iter:
            break
        d = -two_loop(g, S, Y, precondition)
        slope = g @ d
        if slope >= 0:  # not a descent direction: restart from the step matrix
            S.clear()
            Y.clear()
            d = -precondition(g)
            slope = g @ d
        Md = matvec_M(d)
        s = 1.0
        for _ in range(12):
            z1, Mdz1 = z + s * d, Mdz + s * Md
            phi1, g1, extra1 = evaluate(z1, Mdz1)
            evals += 1
            # Armijo, with a slack at the round-off of Phi: near convergence the true
            # decrease falls below the rounding of the summed element energies
            slack = 1e-12 * max(abs(phi), abs(phi1)) if np.isfinite(phi1) else 0.0
            if np.isfinite(phi1) and phi1 <= phi + 1e-4 * s * slope + slack:
                break
            s *= 0.5
        else:
            return False, z, Mdz, extra, {"message": f"line search failed at iteration {it} (|R| = {gn:.3e}, "
                                                     f"tolerance {tol:.3e})", "iterations": it, "evaluations": evals}
        sk, yk = z1 - z, g1 - g
        if yk @ sk > 1e-12 * np.linalg.norm(yk) * np.linalg.norm(sk):
            S.append(sk)
            Y.append(yk)
            if len(S) > memory:
                S.pop(0)
                Y.pop(0)
        z, Mdz, phi, g, extra = z1, Mdz1, phi1, g1, extra1
    return False, z, Mdz, extra, {"message": f"L-BFGS did not converge in {max_iter} iterations (|R| = {gn:.3e}, "
                                             f"tolerance {tol:.3e})", "iterations": max_iter, "evaluations": evals,
                                  "residual": gn, "converged": False, "solve_s": time.perf_counter() - tic}
