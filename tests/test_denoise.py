"""Denoising: the smoothing lambda chosen by the held-out error, and a raw scan end to end."""

import numpy as np
import pytest
from helpers import sphere

import jaxrbf
from jaxrbf.cli import main

AXES = np.array([1.0, 0.6, 0.35])
DIAG = 2 * float(np.linalg.norm(AXES))


def ellipsoid_cloud(n, noise, seed=0):
    """Points on the ellipsoid with semi-axes AXES plus Gaussian noise (a fraction of the
    diagonal per coordinate), and their true outward normals."""
    p, nrm = sphere(n)
    q = p * AXES
    true = nrm / AXES
    true /= np.linalg.norm(true, axis=1, keepdims=True)
    q = q + noise * DIAG * np.random.default_rng(seed).standard_normal(q.shape)
    return q, true


def ellipsoid_distance(x):
    """First-order distance of `x` from the ellipsoid (|q - 1| / |grad q|, q = |x / AXES|)."""
    y = x / AXES
    q = np.linalg.norm(y, axis=1)
    grad = y / AXES / q[:, None]
    return np.abs(q - 1) / np.linalg.norm(grad, axis=1)


@pytest.mark.slow
def test_noise_gets_smoothing_and_clean_input_does_not():
    clean, n_clean = ellipsoid_cloud(2000, 0.0)
    noisy, _ = ellipsoid_cloud(2000, 0.01)
    d = 0.01 * DIAG
    r_clean = jaxrbf.choose_smoothing(clean, n_clean, offset=d, crops=2, crop_points=700)
    r_noisy = jaxrbf.choose_smoothing(noisy, n_clean, offset=d, crops=2, crop_points=700)
    assert r_noisy.smoothing > 0
    assert r_noisy.smoothing > 100 * r_clean.smoothing
    # The report's numbers are what it chose from: the best candidate beats interpolation.
    assert min(r_noisy.objective) < r_noisy.objective[0]
    assert r_noisy.grid[0] == 0 and "denoise: lambda" in r_noisy.summary()
    unit = float(np.linalg.norm(np.ptp(noisy, axis=0))) ** 3
    assert np.isclose(r_noisy.smoothing, r_noisy.relative * unit, rtol=1e-6)


@pytest.mark.slow
def test_every_lambda_from_one_eigendecomposition_matches_the_held_out_error():
    """The path of fits from one eigendecomposition gives, at each lambda, what the tuning
    objective (`held_out_error`, one LU solve per fit) gives on the same split."""
    from jaxrbf._denoise import _crop_errors
    from jaxrbf.kernels import make_kernel

    p, n = ellipsoid_cloud(400, 0.004, seed=4)
    inner = np.arange(0, 400, 2)
    lams = np.array([0.0, 1e-5, 1e-3]) * DIAG**3
    per_point = _crop_errors(p, n, inner, make_kernel("cubic"), 0.02, 1, lams, seed=0)
    test = np.sort(np.random.default_rng(0).choice(inner, len(inner) // 3, replace=False))
    assert per_point.shape == (len(test), 3)
    for i, lam in enumerate(lams):
        ref = float(
            jaxrbf.objectives.held_out_error(
                p, n, kernel="cubic", offset=0.02, smoothing=lam, test=test
            )
        )
        assert np.isclose(per_point[:, i].mean(), ref, rtol=1e-5), (i, per_point[:, i].mean(), ref)


@pytest.mark.slow
def test_choice_is_the_largest_lambda_within_one_standard_error():
    noisy, true = ellipsoid_cloud(1500, 0.008, seed=5)
    r = jaxrbf.choose_smoothing(noisy, true, offset=0.02, crops=2, crop_points=600)
    obj = np.asarray(r.objective)
    best = int(np.argmin(obj))
    chosen = r.grid.index(r.relative)
    assert chosen >= best and obj[chosen] <= obj[best] + r.standard_error
    assert np.all(obj[best : chosen + 1] <= obj[best] + r.standard_error)
    assert chosen == len(obj) - 1 or obj[chosen + 1] > obj[best] + r.standard_error
    assert 0 < r.standard_error < obj[best]


@pytest.mark.slow
def test_choice_is_bounded_by_the_noise():
    """The smoothing is lowered while the crops' fits pass further from their own samples than
    DISCREPANCY noise sigmas (a surface that removed just the noise lies 0.6745 sigma from them)."""
    from jaxrbf._denoise import DISCREPANCY

    noisy, true = ellipsoid_cloud(1500, 0.008, seed=5)
    kw = dict(offset=0.02, crops=2, crop_points=600)
    free = jaxrbf.choose_smoothing(noisy, true, noise=1e9, **kw)  # a bound that never binds
    assert free.lowered_from is None and free.relative > 0
    # the noise estimated from the points: Gaussian noise explains the held-out error's choice
    est = jaxrbf.choose_smoothing(noisy, true, **kw)
    assert est.relative == free.relative and est.lowered_from is None
    assert 0.5 < est.residual <= DISCREPANCY and np.isclose(est.noise, 0.008 * DIAG, rtol=0.3)
    # told the noise is a fifth of that, the choice goes down to a fit that close
    tight = jaxrbf.choose_smoothing(noisy, true, noise=0.0016 * DIAG, **kw)
    assert tight.relative < free.relative
    assert tight.lowered_from[0] == free.relative and tight.lowered_from[1] > DISCREPANCY
    assert tight.residual <= DISCREPANCY
    assert "lowered from lambda" in tight.summary()


@pytest.mark.slow
def test_denoised_fit_is_nearer_the_true_surface():
    noisy, true = ellipsoid_cloud(2000, 0.01, seed=1)
    plain = jaxrbf.fit_surface(noisy, true, offset=0.02, denoise=False)  # (default: "auto")
    # (`fit_surface(..., denoise=True)` makes this choice with 1,000-point crops; the end-to-end
    # test below goes through it.)
    lam = jaxrbf.choose_smoothing(noisy, true, offset=0.02, crops=2, crop_points=600).smoothing
    smooth = jaxrbf.fit_surface(noisy, true, offset=0.02, smoothing=lam)
    err, align = {}, {}
    for name, model in (("plain", plain), ("smooth", smooth)):
        mesh = jaxrbf.polygonize(model, resolution=48)
        err[name] = float(np.mean(ellipsoid_distance(mesh.vertices)))
        x, ok = jaxrbf.project(model, mesh.vertices[::5])
        y = x[ok] / AXES**2  # the true normal direction at x
        truth = y / np.linalg.norm(y, axis=1, keepdims=True)
        align[name] = float(np.mean(np.sum(np.asarray(model.normal(x[ok])) * truth, axis=1)))
    assert err["smooth"] < 0.7 * err["plain"], err
    # Its normals follow the true surface's, where the interpolant's follow the noise.
    assert align["smooth"] > 0.98 and align["smooth"] > align["plain"] + 0.01, align


def test_denoise_bad_input():
    p, n = ellipsoid_cloud(300, 0.0)
    with pytest.raises(jaxrbf.InputError, match="not both"):
        jaxrbf.fit_surface(p, n, smoothing=1e-3, denoise=True)
    with pytest.raises(jaxrbf.InputError, match="lambdas >= 0"):
        jaxrbf.choose_smoothing(p, n, offset=0.01, grid=(0.0, -1.0))
    with pytest.raises(jaxrbf.InputError, match="one shape"):
        jaxrbf.choose_smoothing(p, n[:10], offset=0.01)
    with pytest.raises(jaxrbf.InputError, match="at least 50 points"):
        jaxrbf.choose_smoothing(p[:20], n[:20], offset=0.01)


@pytest.mark.slow
def test_raw_scan_end_to_end(tmp_path, capsys):
    """A bare, noisy point cloud of an ellipsoid with a hole and outliers, from the command line:
    normals estimated, outliers dropped, noise smoothed, the hole closed."""
    p, _ = ellipsoid_cloud(2500, 0.004, seed=2)
    p = p[p[:, 2] < 0.25]  # a hole over the top (a scanner that could not see there)
    rng = np.random.default_rng(3)
    outliers = rng.uniform(-1.3, 1.3, (25, 3)) * [1, 1, 0.8]
    outliers = outliers[ellipsoid_distance(outliers) > 0.15]
    cloud = tmp_path / "scan.ply"
    jaxrbf.io.write_points(cloud, np.vstack([p, outliers]))
    out = tmp_path / "surface.ply"
    code = main(
        ["reconstruct", str(cloud), "-o", str(out), "--resolution", "40"]
        + ["--denoise", "--remove-outliers"]
    )
    err = capsys.readouterr().err
    assert code == 0, err
    assert "estimating them" in err and "outliers" in err and "denoise: lambda" in err
    assert "output mesh is watertight" in err
    mesh = jaxrbf.io.read_mesh(out)
    assert jaxrbf.is_watertight(mesh) and jaxrbf.boundary_loops(mesh) == 0
    near = mesh.vertices[mesh.vertices[:, 2] < 0.2]  # away from the filled hole
    assert np.mean(ellipsoid_distance(near)) < 0.01 * DIAG

    code = main(["reconstruct", str(cloud), "-o", str(tmp_path / "x.ply"), "--denoise", "--tune"])
    err = capsys.readouterr().err
    assert code == 2 and "--tune and --denoise" in err
    assert not (tmp_path / "x.ply").exists()


def test_tune_estimates_normals_of_a_bare_cloud(tmp_path, capsys):
    p, _ = ellipsoid_cloud(600, 0.0)
    cloud = tmp_path / "bare.ply"
    jaxrbf.io.write_points(cloud, p)
    out = tmp_path / "tuned.npz"
    code = main(["tune", str(cloud), "-o", str(out), "--points", "400", "--max-steps", "1"])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    assert "no normals given, estimating them" in captured.err and "objective" in captured.out
    model = jaxrbf.load(out)
    inside, outside = np.asarray(model(np.array([[0.0, 0, 0], [2.0, 0, 0]])))
    assert inside < 0 < outside


# --- the noise estimate ---------------------------------------------------------------------


def cube_samples(n, seed=0):
    """Uniform samples of the surface of the cube [-1, 1]^3 (twelve sharp edges, eight corners)."""
    rng = np.random.default_rng(seed)
    p = rng.uniform(-1, 1, (n, 3))
    axis = rng.integers(0, 3, n)
    p[np.arange(n), axis] = rng.choice([-1.0, 1.0], n)
    return p


def test_noise_estimate_tells_clean_from_noisy():
    from jaxrbf._noise import NOISY_SPACING, estimate_noise

    p, n = sphere(6000)
    diag = float(np.linalg.norm(np.ptp(p, axis=0)))
    clean = estimate_noise(p)
    assert not clean.noisy and clean.relative_spacing < 0.2 * NOISY_SPACING, clean
    assert not estimate_noise(p, n).noisy
    noisy = p + 0.005 * diag * np.random.default_rng(0).standard_normal(p.shape)
    r = estimate_noise(noisy)
    assert r.noisy and r.relative_spacing > 3 * NOISY_SPACING
    # sigma itself: within 15% of the noise added (per coordinate, so across the surface too)
    assert abs(r.relative_diagonal / 0.005 - 1) < 0.15, r.relative_diagonal
    assert abs(r.sigma - r.relative_diagonal * r.diagonal) < 1e-12
    assert "noisy" in r.summary() and "clean enough" in clean.summary()
    # Noise of 0.1% of the diagonal, at this density a fifth of a spacing, is noisy too.
    assert estimate_noise(p + 0.2 * diag * (noisy - p)).noisy


def test_noise_estimate_ignores_creases_and_sees_misregistration():
    from jaxrbf._noise import estimate_noise

    cube = cube_samples(8000)
    r = estimate_noise(cube)
    # A plane fitted across an edge leaves about a spacing; the quadric's low quantile does not.
    assert not r.noisy and r.relative_spacing < 0.01, r
    assert r.rough_fraction > 0  # the neighbourhoods across the edges are rough ...
    diag = float(np.linalg.norm(np.ptp(cube, axis=0)))
    noisy = cube + 0.0025 * diag * np.random.default_rng(1).standard_normal(cube.shape)
    assert estimate_noise(noisy).noisy  # ... and noise is seen through them
    # Two overlapping scans of a sphere, registered 0.2 of a spacing apart along the normal.
    p, _ = sphere(4000)
    spacing = estimate_noise(p).spacing
    q, _ = sphere(4000, radius=1 + 0.2 * spacing)
    rot = np.linalg.qr(np.random.default_rng(2).standard_normal((3, 3)))[0]
    two = estimate_noise(np.vstack([p, q @ rot.T]))
    assert two.noisy, two


def test_noise_estimate_with_normals_keeps_to_each_face_of_a_thin_part():
    from jaxrbf._noise import estimate_noise

    # A closed plate 1.5 spacings thick: 12 neighbours reach the other face everywhere, so a
    # fit across both faces reads half the thickness as noise (0.55 spacings before).
    rng = np.random.default_rng(5)
    m = 12000
    xy = rng.uniform(-1, 1, (m, 2))
    spacing = 0.5 * np.sqrt(8 / m)
    half = 0.75 * spacing
    up = rng.random(m) < 0.5
    p = np.column_stack([xy, np.where(up, half, -half)])
    n = np.zeros_like(p)
    n[:, 2] = np.where(up, 1.0, -1.0)
    assert estimate_noise(p).noisy  # without normals the faces cannot be told apart
    thin = estimate_noise(p, n)
    assert not thin.noisy and thin.relative_spacing < 0.01, thin
    noisy = p + 0.2 * thin.spacing * rng.standard_normal(p.shape)
    assert estimate_noise(noisy, n).noisy  # ... and noise is seen through them
    # normals flipped at random are no thin part: the first fit stands
    flips = np.where(rng.random(m) < 0.5, -1.0, 1.0)[:, None]
    flat = np.column_stack([xy, np.zeros(m)])
    assert not estimate_noise(flat, n * flips).noisy


def test_noise_estimate_widens_for_large_noise_and_2d():
    from jaxrbf._noise import estimate_noise

    p, _ = sphere(20000)
    diag = float(np.linalg.norm(np.ptp(p, axis=0)))
    # 0.5% of the diagonal is ~0.7 spacings here: 12 neighbours would follow it.
    noisy = p + 0.005 * diag * np.random.default_rng(3).standard_normal(p.shape)
    r = estimate_noise(noisy)
    assert r.k == 12 and r.thinned > 1
    assert abs(r.relative_diagonal / 0.005 - 1) < 0.15, r.relative_diagonal
    t = np.linspace(0, 2 * np.pi, 3000, endpoint=False)
    circle = np.stack([np.cos(t), np.sin(t)], axis=1)
    assert not estimate_noise(circle).noisy
    shaken = circle + 0.004 * np.random.default_rng(4).standard_normal(circle.shape)
    assert estimate_noise(shaken).noisy


def test_noise_estimate_bad_input():
    from jaxrbf._noise import estimate_noise

    p, n = sphere(100)
    with pytest.raises(jaxrbf.InputError, match="at least 8"):
        estimate_noise(p, k=3)
    with pytest.raises(jaxrbf.InputError, match="at least 13 points"):
        estimate_noise(p[:10])
    with pytest.raises(jaxrbf.InputError, match="shape of `points`"):
        estimate_noise(p, n[:5])
    with pytest.raises(jaxrbf.InputError, match="finite and non-zero"):
        estimate_noise(p, 0 * n)
    with pytest.raises(jaxrbf.InputError, match="threshold"):
        estimate_noise(p, threshold=0)
    with pytest.raises(jaxrbf.InputError, match="all points coincide"):
        estimate_noise(np.zeros((50, 3)))


# --- the lambda grid ------------------------------------------------------------------------


@pytest.mark.slow
def test_grid_reaches_past_the_old_top_and_extends_from_its_top():
    from jaxrbf import _denoise

    assert _denoise.GRID[0] == 0 and _denoise.GRID[-1] >= 1.0  # the old top was 0.1
    steps = np.diff(np.log10(_denoise.GRID[1:]))
    assert np.allclose(steps, 0.25)
    noisy, true = ellipsoid_cloud(1500, 0.008, seed=5)
    kw = dict(offset=0.02, crops=2, crop_points=600)
    full = jaxrbf.choose_smoothing(noisy, true, **kw)
    assert full.extended == 0 and not full.at_top
    # A grid whose top sits below the choice: extended upward until the choice is inside it,
    # and the same choice as the full grid (same crops, same eigendecompositions' errors).
    short = tuple(g for g in full.grid if g < full.relative / 50)
    r = jaxrbf.choose_smoothing(noisy, true, grid=short, **kw)
    assert r.extended >= 1 and not r.at_top and len(r.objective) == len(r.grid)
    assert np.isclose(r.relative, full.relative, rtol=1e-9), (r.relative, full.relative)
    i = int(np.argmin(np.abs(np.asarray(full.grid) - r.grid[-1])))
    assert np.isclose(r.objective[-1], full.objective[i], rtol=1e-9)
    assert "extended" in r.summary()


def test_choice_on_the_top_of_the_grid_is_reported(monkeypatch):
    from jaxrbf import _denoise

    monkeypatch.setattr(_denoise, "MAX_EXTENSIONS", 0)
    noisy, true = ellipsoid_cloud(800, 0.008, seed=6)
    r = jaxrbf.choose_smoothing(
        noisy, true, offset=0.02, crops=1, crop_points=500, grid=(0.0, 1e-8, 1e-7)
    )
    assert r.at_top and r.extended == 0 and r.relative == 1e-7
    assert "the choice is the top of the grid" in r.summary()
