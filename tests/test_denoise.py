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


def test_denoised_fit_is_nearer_the_true_surface():
    noisy, true = ellipsoid_cloud(2000, 0.01, seed=1)
    plain = jaxrbf.fit_surface(noisy, true, offset=0.02)
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
