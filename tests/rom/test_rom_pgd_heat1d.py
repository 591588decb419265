"""PGD vademecum of heat1d_source (pgd-vademecum-cutting §2): the srb / prb identities of
eqs. 18-19 with one mode, srb exact once the modes span the space, the PGD against the
closed-form Green's function (the weighted SVD it converges to), bad positions."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import scipy.sparse.linalg as spla

from tissuebench.cases.scene import load
from tissuebench.refsolvers.line_models import solve_static
from tissuebench.rom import make_method
from tissuebench.rom.pgd import build_vademecum, family_from_training, pgd_training
from tissuebench.rom.pgd.projections import srb_beta_in_modes

POSITIONS = (0.5, 0.3, 0.71, 0.123)  # nodes and points between nodes (ci: h = 0.02)


@pytest.fixture(scope="module")
def scene():
    return load("heat1d_source")


@pytest.fixture(scope="module")
def training(scene):
    return pgd_training(scene)


@pytest.mark.parametrize("s_p", POSITIONS)
def test_one_mode_prb_srb_identity(training, s_p):
    srb = make_method("pgd", n_modes=1, projection="srb").build(training)
    prb = make_method("pgd", n_modes=1, projection="prb").build(training)
    vad = prb.vademecum
    rows, vals = vad.family.load_at(s_p)
    S_p = vad.S_at(s_p)[0]
    gamma, alpha = vad.gamma[0], vad.alpha[0, 0]
    beta_srb = srb_beta_in_modes(vad, rows, vals)[0]
    beta_prb = prb.proj.beta(rows, vals)[0]
    # eq. 18 (algebra) and eq. 19 (S is the exact projection given X: beta_srb = S(s_p))
    assert beta_prb == pytest.approx(gamma / alpha * beta_srb, rel=1e-12)
    assert beta_srb == pytest.approx(S_p, rel=1e-12)
    assert beta_prb == pytest.approx(gamma / alpha * S_p, rel=1e-12)
    # the online steps: prb coefficient on X is beta_prb S(s_p); srb reproduces S(s_p) X
    assert prb.step({"position": s_p}).q[0] == pytest.approx(beta_prb * S_p, rel=1e-12)
    u_srb = srb.reconstruct(srb.step({"position": s_p}))
    u_vad = np.zeros(vad.family.ndof)
    u_vad[vad.family.free_dofs] = vad.field(s_p)
    assert np.allclose(u_srb, u_vad, rtol=0, atol=1e-12 * np.abs(u_vad).max())
    assert abs(gamma / alpha - 1.0) > 0.1  # prb is not consistent: beta_prb != 1 (here 1.256)


def test_srb_exact_once_the_modes_span_the_space(scene, training):
    fam = family_from_training(training)
    model = make_method("pgd", n_modes=fam.n_free, projection="srb", max_fixed_point=30).build(training)
    assert model.n_reduced == fam.n_free  # 49 modes span the 49 free dofs
    u_fe = solve_static(training.system)  # the scene's source at s = 0.5
    u = model.reconstruct(model.step({"position": 0.5}))
    assert np.linalg.norm(u - u_fe) / np.linalg.norm(u_fe) < 1e-11
    lu = spla.splu(fam.K.tocsc())
    for s_p in POSITIONS[1:]:
        rows, vals = fam.load_at(s_p)
        f = np.zeros(fam.n_free)
        f[rows] = vals
        u = model.reconstruct(model.step({"position": s_p}))[fam.free_dofs]
        assert np.linalg.norm(u - lu.solve(f)) / np.linalg.norm(u) < 1e-11
    # a few modes are not enough (the error the span closes)
    small = make_method("pgd", n_modes=5, projection="srb").build(training)
    u5 = small.reconstruct(small.step({"position": 0.5}))
    assert np.linalg.norm(u5 - u_fe) / np.linalg.norm(u_fe) > 1e-3


def _green(x, s, q=1.0, k=1.0):
    """u of k u'' = q delta(x - s), u(0) = u(1) = 0 (line_models' sign convention)."""
    return (q / k) * (np.maximum(x[:, None] - s[None, :], 0.0) - (1.0 - s[None, :]) * x[:, None])


def test_pgd_against_the_closed_form_green_function(training):
    fam = family_from_training(training)
    x = fam.x[fam.free_dofs]
    G = _green(x, fam.coords)  # (n_free, n_s)
    # P1 FE is nodally exact for point sources at nodes: the tensor PGD approximates is G
    U = spla.splu(fam.K.tocsc()).solve(fam.loads.toarray())
    assert np.abs(U - G).max() < 1e-13
    # energy norm of K ⊗ W: the greedy PGD is the weighted SVD of L^T G W^(1/2), K = L L^T
    L = np.linalg.cholesky(fam.K.toarray())
    sw = np.sqrt(fam.weights)
    sig = np.linalg.svd(L.T @ G * sw, compute_uv=False)

    def energy(E):
        return np.linalg.norm(L.T @ E * sw)

    vad = build_vademecum(fam, n_modes=8, tol=0.0, max_fixed_point=2000, fixed_point_tol=1e-11)
    errs = [energy(vad.truncated(n).X @ vad.truncated(n).S.T - G) for n in range(1, 9)]
    assert all(b < a for a, b in zip(errs, errs[1:]))
    tails = [np.sqrt(np.sum(sig[n:] ** 2)) for n in range(1, 9)]
    assert np.allclose(errs[:4], tails[:4], rtol=1e-6), (errs, tails)  # converged fixed points
    assert all(vad.record.converged[:4])
    # max-norm error against G decreases with the modes: the first and the eighth
    e1, e8 = (np.abs(vad.truncated(n).X @ vad.truncated(n).S.T - G).max() for n in (1, 8))
    assert e8 < 0.5 * e1


def test_positions_outside_the_domain(scene):
    narrow = dataclasses.replace(scene, model_params={**scene.model_params, "source_range": [0.2, 0.8]})
    tr = pgd_training(narrow)
    srb = make_method("pgd", n_modes=3, projection="srb").build(tr)
    prb = make_method("pgd", n_modes=3, projection="prb").build(tr)
    assert srb.envelope == {"position": (0.2, 0.8)}
    r = srb.step({"position": 0.1})  # on the mesh, outside the vademecum: projected, flagged
    assert r.status == "extrapolation" and r.q is not None and "outside" in r.message
    r = prb.step({"position": 0.1})  # prb needs S(0.1): refused
    assert r.status == "failed" and r.q is None and "S(s) undefined" in r.message
    for model in (srb, prb):
        r = model.step({"position": 1.5})  # off the mesh
        assert r.status == "failed" and "off the mesh" in r.message
        assert model.step({"position": 0.5}).status == "ok"
    with pytest.raises(ValueError, match="position"):
        srb.step({"position": float("nan")})
    with pytest.raises(ValueError, match="missing"):
        srb.step({"load_factor": 1.0})


@pytest.mark.parametrize("opts, match", [({"n_modes": 0}, "n_modes"), ({"projection": "pod"}, "projection"),
                                         ({"tol": -1}, "tol"), ({"seed": 1.5}, "seed"),
                                         ({"max_fixed_point": True}, "max_fixed_point")])
def test_bad_options(opts, match):
    with pytest.raises(ValueError, match=match):
        make_method("pgd", **opts)


def test_fixed_point_not_converging_is_reported_in_the_model_info(training):
    model = make_method("pgd", n_modes=3, max_fixed_point=2, fixed_point_tol=1e-14).build(training)
    info = model.info
    assert info["fixed_point_iterations"] == [2, 2, 2] and info["fixed_point_converged"] == [False] * 3
    assert "not converged in 3 mode(s)" in info["message"] and info["stop_reason"] == "max_modes"
    assert "stiffness K" in info["operators"]  # the vademecum uses operators, no snapshots
    assert model.step({"position": 0.5}).status == "ok"  # the modes are usable, the record says how good
