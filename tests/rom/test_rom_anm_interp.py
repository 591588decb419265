"""Interpolated ANM-POD (anm_pod_interp): an SVK cantilever whose point load moves along the top face."""
import numpy as np
import pytest

from tissuebench.cases.meshes import box_mesh
from tissuebench.refsolvers import Dirichlet, PointLoad, Problem, SaintVenantKirchhoff, make_backend
from tissuebench.refsolvers.newton import newton_solve
from tissuebench.rom.anm_pod import AnmPod
from tissuebench.rom.anm_interp import AnmPodInterp, AnmPodInterpModel, rotate_polynomial
from tissuebench.rom.base import METHODS, Training, make_method
from tissuebench.rom.interpolation import grassmann_exp, grassmann_log, principal_angles
from tissuebench.rom.polynomial import ReducedPolynomial

# 4 x 1 x 1 cantilever, E = 1e3, 10 N at x on the top-face centre line: tip deflection
# 1.58 (40 % of the length) with the load at the tip, so the path is well nonlinear
MESH = box_mesh((4.0, 1.0, 1.0), (16, 2, 2), "tetra")
H = 0.25  # node spacing along x
COARSE, FINE = [2.0, 3.0, 4.0], [2.0, 2.5, 3.0, 3.5, 4.0]
HELD = [2.25, 2.6, 2.75, 3.25, 3.4, 3.75]  # 2.6 and 3.4 lie between nodes
N_MODES = 4  # = the rank of the 4 snapshots per position


def _problem(x, force=10.0):
    """The load at any x: split linearly between the two nodes around x (continuous in x)."""
    k = int(np.floor(x / H + 1e-9))
    t = x / H - k
    loads = [PointLoad(lambda X, xn=xn: np.isclose(X[:, 0], xn) & np.isclose(X[:, 1], 0.5) & np.isclose(X[:, 2], 1.0),
                       np.array([0.0, 0.0, -force * wt]))
             for xn, wt in ((k * H, 1.0 - t), ((k + 1) * H, t)) if wt > 1e-12]
    return Problem(MESH, SaintVenantKirchhoff(1e3, 0.3), "P1", dirichlet=[Dirichlet(lambda X: X[:, 0] < 1e-9)],
                   loads=loads)


@pytest.fixture(scope="module")
def family():
    """{x: Training} of Newton paths (lam = 0.25 ... 1) at every lattice and held-out position."""
    out = {}
    for x in sorted(set(FINE + HELD)):
        be = make_backend("skfem", _problem(x))
        res = newton_solve(be, 1.0, n_increments=4, max_increment=0.25)
        assert res.success
        lams = [inc.load_factor for inc in res.increments if inc.converged]
        out[x] = Training(np.column_stack(res.states), [{"load_factor": lam} for lam in lams], be)
    return out


@pytest.fixture(scope="module")
def models(family):
    """{(lattice, basis_interpolation, align): model}."""
    out = {}
    for name, lattice in (("coarse", COARSE), ("fine", FINE)):
        training = Training(groups={x: family[x] for x in lattice})
        for bi in ("podi", "grassmann"):
            for align in ("procrustes", "modes"):
                method = AnmPodInterp(n_modes=N_MODES, basis_interpolation=bi, align=align)
                out[name, bi, align] = method.build(training)
    return out


def _path(model, x, training, basis=None):
    """Reconstructed states (n_dof, n_lam) at position x along the training's load factors."""
    cols = []
    for p in training.parameters:
        res = model.step({"load_factor": p["load_factor"], "position": x})
        assert res.status == "ok", res.message
        if basis is not None:
            res.info["basis"] = basis
        cols.append(model.reconstruct(res))
    return np.column_stack(cols)


def _path_error(model, x, training, basis=None):
    """Relative l2 over the load path: ||U_rom - U_ref||_F / ||U_ref||_F."""
    return np.linalg.norm(_path(model, x, training, basis) - training.snapshots) / np.linalg.norm(training.snapshots)


def _nearest_error(model, lattice, x, training):
    """The stored model of the nearest lattice position used at x (no interpolation)."""
    near = lattice[int(np.argmin(np.abs(np.subtract(lattice, x))))]
    return _path_error(model, near, training)


# ---------------------------------------------------------------- pieces
def test_rotate_polynomial_is_the_same_model_in_rotated_coordinates():
    rng = np.random.default_rng(0)
    m = 3
    Q = rng.standard_normal((m, m, m))
    C = rng.standard_normal((m, m, m, m))
    poly = ReducedPolynomial(rng.standard_normal((m, m)), Q + Q.transpose(0, 2, 1), C, rng.standard_normal(m))
    R = np.linalg.qr(rng.standard_normal((m, m)))[0]
    rot = rotate_polynomial(poly, R)
    q = rng.standard_normal(m)
    np.testing.assert_allclose(rot.force(R.T @ q), R.T @ poly.force(q), atol=1e-12)
    np.testing.assert_allclose(rot.tangent(R.T @ q), R.T @ poly.tangent(q) @ R, atol=1e-12)
    np.testing.assert_allclose(rot.f, R.T @ poly.f, atol=1e-14)


def test_options_and_training_are_validated(family):
    assert METHODS["anm_pod_interp"] is AnmPodInterp
    with pytest.raises(ValueError, match=r"basis_interpolation='spline'; valid: \['podi', 'grassmann'\]"):
        make_method("anm_pod_interp", basis_interpolation="spline")
    with pytest.raises(ValueError, match="align"):
        AnmPodInterp(align="none")
    with pytest.raises(ValueError, match="order"):
        AnmPodInterp(order=0)
    with pytest.raises(ValueError, match=">= 2 load positions"):
        AnmPodInterp().build(Training(groups={2.0: family[2.0]}))
    with pytest.raises(ValueError, match="position 3"):
        AnmPodInterp().build(Training(groups={2.0: family[2.0], 3.0: Training()}))


# ---------------------------------------------------------------- stored positions
@pytest.mark.parametrize("bi", ["podi", "grassmann"])
def test_a_stored_position_reproduces_its_own_anm_pod(family, models, bi):
    model = models["fine", bi, "procrustes"]
    assert isinstance(model, AnmPodInterpModel) and model.n_reduced == N_MODES
    for x in (2.0, 3.5, 4.0):  # 3.5 and 4.0 are rotated by the alignment chain (R != I)
        own = AnmPod(n_modes=N_MODES, order=6).build(family[x])
        for p in family[x].parameters:
            lam = p["load_factor"]
            res = model.step({"load_factor": lam, "position": x})
            assert res.status == "ok" and res.info["distance"] == 0.0 and list(res.info["indices"]) == [FINE.index(x)]
            u_own = own.reconstruct(own.step({"load_factor": lam}))
            assert np.linalg.norm(model.reconstruct(res) - u_own) < 1e-8 * np.linalg.norm(u_own)
    assert not np.allclose(model.info["rotations"][-1], np.eye(N_MODES))


# ---------------------------------------------------------------- held-out positions
def test_held_out_errors_are_finite_and_shrink_with_the_lattice(family, models):
    err = {}
    for name, lattice in (("coarse", COARSE), ("fine", FINE)):
        for bi in ("podi", "grassmann"):
            err[name, bi] = np.array([_path_error(models[name, bi, "procrustes"], x, family[x]) for x in HELD])
        err[name, "nearest"] = np.array([_nearest_error(models[name, "podi", "procrustes"], lattice, x, family[x])
                                         for x in HELD])
    for (name, kind), e in err.items():
        assert np.all(np.isfinite(e)) and e.max() < 0.3, (name, kind, e)
    for bi in ("podi", "grassmann"):
        # measured mean 2.9e-2 (coarse) -> 8.2e-3 (fine); nearest stored model 1.4e-1 / 9.2e-2
        assert err["coarse", bi].max() < 0.08 and err["fine", bi].max() < 0.03
        assert err["fine", bi].mean() < 0.5 * err["coarse", bi].mean()
        for name in ("coarse", "fine"):
            assert err[name, bi].mean() < 0.5 * err[name, "nearest"].mean()
    # Procrustes-aligned neighbours: two-neighbour PODI lies on the Grassmann geodesic (another speed)
    np.testing.assert_allclose(err["coarse", "podi"], err["coarse", "grassmann"], rtol=1e-2)


def test_mode_matching_alignment_runs_and_is_less_accurate_here(family, models):
    # measured mean: 8.2e-2 / 2.4e-2 with matched modes, 2.9e-2 / 8.2e-3 with Procrustes
    for name in ("coarse", "fine"):
        for bi in ("podi", "grassmann"):
            e_modes = np.mean([_path_error(models[name, bi, "modes"], x, family[x]) for x in HELD])
            e_proc = np.mean([_path_error(models[name, bi, "procrustes"], x, family[x]) for x in HELD])
            assert np.isfinite(e_modes) and e_proc < e_modes < 0.15


def test_grassmann_basis_is_expressed_in_the_aligned_coordinates(family, models):
    """The tensors live in aligned coordinates; the Grassmann basis must too (Procrustes after exp)."""
    model = models["fine", "grassmann", "modes"]  # matched modes: exp does not land on the aligned basis
    podi = models["fine", "podi", "modes"]
    x = 2.25  # the midpoint of [2, 2.5]
    res = model.step({"load_factor": 1.0, "position": x})
    A = model.basis_at(x)
    i, j = res.info["indices"][np.argsort(-res.info["weights"])]  # nearest first
    w = res.info["weights"].min()
    G_paper = grassmann_exp(model.bases[i], w * grassmann_log(model.bases[i], model.bases[j]), paper_form=True)
    G_ours = grassmann_exp(model.bases[i], w * grassmann_log(model.bases[i], model.bases[j]))
    for G in (G_paper, G_ours):  # one subspace, three coordinate systems
        assert principal_angles(A, G).max() < 1e-10
    B = podi.basis_at(x)
    # measured 0.018 (vs PODI's basis), 0.14 without the rotation, 2.9 in the paper's form
    assert np.linalg.norm(A - B) < 0.05 < np.linalg.norm(G_ours - B) < 1.0 < np.linalg.norm(G_paper - B)
    e = _path_error(model, x, family[x])
    e_unrotated = _path_error(model, x, family[x], basis=G_ours)
    e_paper = _path_error(model, x, family[x], basis=G_paper)
    assert e < 0.9 * e_unrotated and e_unrotated < 0.1 and e_paper > 0.3  # measured 2.7e-2, 3.6e-2, 1.4
    # with Procrustes-aligned neighbours the exp form already lands in the aligned coordinates
    aligned = models["fine", "grassmann", "procrustes"]
    G = grassmann_exp(aligned.bases[i], w * grassmann_log(aligned.bases[i], aligned.bases[j]))
    assert np.linalg.norm(aligned.basis_at(x) - G) < 1e-12


# ---------------------------------------------------------------- statuses, cache, timings
def test_out_of_envelope_is_flagged_extrapolation(family, models):
    model = models["coarse", "podi", "procrustes"]
    assert model.envelope == {"load_factor": (0.25, 1.0), "position": (2.0, 4.0)}
    res = model.step({"load_factor": 0.5, "position": 1.7})
    assert res.status == "extrapolation" and res.info["distance"] == pytest.approx(0.3)
    assert "outside the stored positions [2, 4]" in res.message and np.all(np.isfinite(model.reconstruct(res)))
    assert model.step({"load_factor": 1.2, "position": 3.0}).status == "extrapolation"
    coarse = Training(groups={x: family[x] for x in COARSE})
    paper = AnmPodInterp(n_modes=N_MODES, order=2, max_segments=1).build(coarse)
    assert paper.step({"load_factor": 1.0, "position": 2.5}).status == "beyond_validity"
    with pytest.raises(ValueError, match="position"):
        model.step({"load_factor": 0.5})


def test_repeated_positions_use_the_cache_and_timings_are_reported(models):
    model = models["fine", "grassmann", "procrustes"]
    first = model.step({"load_factor": 0.4, "position": 3.1})
    again = model.step({"load_factor": 0.9, "position": 3.1})
    assert set(first.info["timings"]) == {"tensors", "series", "evaluation"}
    assert first.info["timings"]["tensors"] > 0 and again.info["timings"]["tensors"] == 0.0
    # the step leaves the full-size basis alone; reconstruct interpolates it once per position
    assert "basis" not in first.info and "basis" not in model._cache[3.1][1]
    u1, u2 = model.reconstruct(first), model.reconstruct(again)
    assert np.all(np.isfinite(u1)) and np.all(np.isfinite(u2))
    assert model.basis_at(3.1) is model.basis_at(3.1)
    np.testing.assert_array_equal(model.step({"load_factor": 0.4, "position": 3.1}).q, first.q)
