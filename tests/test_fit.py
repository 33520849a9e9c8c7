import jax.numpy as jnp
import numpy as np
import pytest
from conftest import data_file
from helpers import franke
from scipy.interpolate import RBFInterpolator

import jaxrbf
from jaxrbf import InputError, SolveError
from jaxrbf._fit import DENSE_LIMIT

RNG = np.random.default_rng(42)
X = RNG.random((300, 3))
Y = np.sin(3 * X[:, 0]) + X[:, 1] * X[:, 2]
Q = RNG.random((500, 3))

SCIPY_NAMES = {"thin-plate": "thin_plate_spline", "inverse-multiquadric": "inverse_multiquadric"}
CASES = [
    ("cubic", None),
    ("linear", None),
    ("thin-plate", None),
    ("gaussian", 0.4),
    ("multiquadric", 0.5),
    ("inverse-multiquadric", 0.5),
]


@pytest.mark.slow
@pytest.mark.parametrize("kernel, radius", CASES)
def test_matches_scipy_rbfinterpolator(kernel, radius):
    model = jaxrbf.fit(X, Y, kernel=kernel, radius=radius)
    ref = RBFInterpolator(
        X,
        Y,
        kernel=SCIPY_NAMES.get(kernel, kernel),
        degree=1,
        epsilon=1 / radius if radius else 1.0,
    )
    np.testing.assert_allclose(np.asarray(model(Q)), ref(Q), atol=1e-7 * np.abs(Y).max())


@pytest.mark.slow
@pytest.mark.parametrize("solver", ["lu", "cholesky", "cg", "gmres"])
@pytest.mark.parametrize("kernel, radius", CASES + [("wendland", 1.2)])
def test_interpolates_its_constraints(solver, kernel, radius):
    model = jaxrbf.fit(X, Y, kernel=kernel, radius=radius, solver=solver)
    tol = 1e-7 if solver == "gmres" else 1e-9  # GMRES stops at its tolerance (1e-8)
    np.testing.assert_allclose(np.asarray(model(X)), Y, atol=tol * np.abs(Y).max())
    assert float(model.residual) < tol


@pytest.mark.parametrize("degree", [-1, 0, 1])
def test_degrees_for_positive_definite_kernel(degree):
    model = jaxrbf.fit(X, Y, kernel="gaussian", radius=0.4, degree=degree, solver="cholesky")
    np.testing.assert_allclose(np.asarray(model(X)), Y, atol=1e-8)
    assert model.coeffs.shape == ({-1: 0, 0: 1, 1: 4}[degree],)


@pytest.mark.parametrize("kernel", ["cubic", "thin-plate", "linear"])
def test_reproduces_linear_polynomials(kernel):
    a = np.array([0.3, -1.2, 2.0])
    y = X @ a + 0.7
    degree = 1
    model = jaxrbf.fit(X, y, kernel=kernel, degree=degree)
    np.testing.assert_allclose(np.asarray(model(Q)), Q @ a + 0.7, atol=1e-9)
    np.testing.assert_allclose(np.asarray(model.weights), 0, atol=1e-9)


def test_scale_invariance_of_polyharmonic_fit():
    m1 = jaxrbf.fit(X, Y)
    m2 = jaxrbf.fit(1000 * X + 5, Y)
    np.testing.assert_allclose(np.asarray(m2(1000 * Q + 5)), np.asarray(m1(Q)), atol=1e-8)


def test_radius_is_in_input_units():
    m1 = jaxrbf.fit(X, Y, kernel="gaussian", radius=0.4)
    m2 = jaxrbf.fit(10 * X, Y, kernel="gaussian", radius=4.0)
    np.testing.assert_allclose(np.asarray(m2(10 * Q)), np.asarray(m1(Q)), atol=1e-7)


def test_two_dimensional_franke():
    g = np.random.default_rng(1).random((400, 2))
    model = jaxrbf.fit(g, franke(g[:, 0], g[:, 1]), kernel="thin-plate")
    t = np.random.default_rng(2).random((300, 2)) * 0.8 + 0.1
    assert np.abs(np.asarray(model(t)) - franke(t[:, 0], t[:, 1])).max() < 0.02


def test_smoothing_approximates():
    noisy = Y + 0.05 * np.random.default_rng(3).standard_normal(len(Y))
    exact = jaxrbf.fit(X, noisy)
    smooth = jaxrbf.fit(X, noisy, smoothing=1e-2)
    ref = RBFInterpolator(X, noisy, kernel="cubic", smoothing=1e-2)
    np.testing.assert_allclose(np.asarray(smooth(Q)), ref(Q), atol=1e-9)
    big = jaxrbf.fit(
        7 * X, noisy, smoothing=1e-2
    )  # smoothing is in the input's units, like scipy's
    ref7 = RBFInterpolator(7 * X, noisy, kernel="cubic", smoothing=1e-2)
    np.testing.assert_allclose(np.asarray(big(7 * Q)), ref7(7 * Q), atol=1e-9)
    assert np.abs(np.asarray(smooth(X)) - noisy).max() > 1e-3  # no longer interpolates
    assert np.abs(np.asarray(exact(X)) - noisy).max() < 1e-8


def test_gmres_reports_iterations(capsys):
    jaxrbf.fit(X, Y, solver="gmres", verbose=True)
    err = capsys.readouterr().err
    assert "iterations" in err and "relative residual" in err


# --- bad input: every message ---------------------------------------------------------------


def test_error_values_shape():
    with pytest.raises(InputError, match=r"`values` must have shape \(300,\)"):
        jaxrbf.fit(X, Y[:-1])


def test_error_points_not_2d():
    with pytest.raises(InputError, match="`points` must be a 2-dimensional array"):
        jaxrbf.fit(X[:, 0], Y)


def test_error_nan_points():
    bad = X.copy()
    bad[5, 1] = np.nan
    with pytest.raises(InputError, match="1 row with NaN or infinite values"):
        jaxrbf.fit(bad, Y)


def test_error_nan_values():
    bad = Y.copy()
    bad[[1, 2]] = np.inf
    with pytest.raises(InputError, match="2 NaN or infinite entries"):
        jaxrbf.fit(X, bad)


def test_error_duplicates():
    dup = np.vstack([X, X[:1]])
    with pytest.raises(InputError, match="1 duplicate points .first: row 300"):
        jaxrbf.fit(dup, np.append(Y, 1.0))


def test_error_all_zero_values():
    with pytest.raises(InputError, match="only solution is f = 0"):
        jaxrbf.fit(X, np.zeros(len(X)))


def test_error_coplanar_points():
    flat = X.copy()
    flat[:, 2] = 0.5
    with pytest.raises(InputError, match="lie on one plane"):
        jaxrbf.fit(flat, Y)
    jaxrbf.fit(flat[:, :2], Y)  # the same data in 2-D is fine


def test_error_degree_too_low():
    with pytest.raises(InputError, match="cubic kernel needs a polynomial of degree >= 1"):
        jaxrbf.fit(X, Y, degree=0)


def test_error_unknown_solver_and_degree():
    with pytest.raises(InputError, match="unknown solver 'qr'"):
        jaxrbf.fit(X, Y, solver="qr")
    with pytest.raises(InputError, match="`degree` must be -1"):
        jaxrbf.fit(X, Y, degree=2)
    with pytest.raises(InputError, match="`smoothing` must be a number >= 0"):
        jaxrbf.fit(X, Y, smoothing=-1)


def test_error_too_few_points():
    with pytest.raises(InputError, match="cannot determine a degree-1 polynomial"):
        jaxrbf.fit(X[:4], Y[:4])


def test_dense_limit_refused_before_lapack():
    n = DENSE_LIMIT  # with the 4 polynomial terms this is above the limit
    pts = np.random.default_rng(0).random((n, 3))
    with pytest.raises(InputError, match="too many for the dense lu solver"):
        jaxrbf.fit(pts, pts[:, 0], method="dense")
    with pytest.raises(InputError, match="too many for the dense cholesky solver"):
        jaxrbf.fit(pts, pts[:, 0], solver="cholesky")


def test_singular_system_raises():
    # a huge Gaussian radius makes the kernel matrix numerically singular
    with pytest.raises(SolveError, match="does not reproduce its constraints|singular"):
        jaxrbf.fit(X, Y, kernel="gaussian", radius=1e4, degree=-1)


def test_gmres_iteration_cap_is_in_iterations():
    # 5 iterations cannot solve a 300-point cubic system: a clear error, not a silent bad fit
    with pytest.raises(SolveError, match="gmres stopped after 1 restart cycles"):
        jaxrbf.fit(X, Y, solver="gmres", max_steps=5)


def test_a_residual_within_the_rounding_of_large_weights_is_accepted():
    # the floor is what rounding alone leaves when B x is evaluated with these weights
    from jaxrbf._fit import FLOOR_TOL, RESIDUAL_TOL, allowed_residual
    from jaxrbf._system import rounding_floor

    m = jaxrbf.fit(X, Y)
    x = np.asarray(m.centres)
    w, a = np.asarray(m.weights), np.asarray(m.coeffs)
    r = np.linalg.norm(x[:, None] - x[None], axis=-1)
    aw = np.abs(m.kernel(r)) @ np.abs(w) + np.abs(np.c_[np.ones(len(x)), x]) @ np.abs(a)
    want = np.sqrt(len(x)) * np.finfo(float).eps * aw.max() / np.abs(Y).max()
    got = float(rounding_floor(m.kernel, m.centres, 1, 0.0, m.weights, m.coeffs, jnp.asarray(Y)))
    assert got == pytest.approx(want, rel=1e-6)
    # accepted up to the floor, within FLOOR_TOL: a singular system's floor is no excuse
    assert allowed_residual(0.0) == RESIDUAL_TOL
    assert allowed_residual(8e-6) == 8e-6
    assert allowed_residual(1e3) == FLOOR_TOL


def test_a_mesh_of_few_vertices_and_many_open_pieces_gives_a_mesh():
    # the beetle's .obj as it comes (1,148 vertices, 33 open pieces): it was sampled at 1,148
    # points (as many as its vertices), fitted for its slabs by CG to a residual of 1.36e-6, and
    # refused as nearly singular (> 1e-6) though float64 could not do better for its weights
    # (floor 8e-6); now 10,000 samples by default, and that fit accepted
    from jaxrbf import surface_from
    from jaxrbf._reconstruct import MESH_MIN_POINTS, fit_surface_samples

    path = data_file("beetle.obj")
    fitted = fit_surface_samples(path, points=1148, method="dense", solver="cg")
    assert float(fitted[0].residual) < 1e-4  # 1.36e-6 here, CG on this machine
    assert len(fitted.shells[0]) == 1148  # every sample on an open shell
    assert len(surface_from(path)[0]) == MESH_MIN_POINTS
