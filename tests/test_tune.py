"""Objectives (held-out, k-fold, Rippa's leave-one-out), `tune`, `grid_search`, the defaults from
the point spacing, gradient-based shape fitting, and the `tune` command."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
import pytest
from helpers import sphere, sphere_sdf

import jaxrbf
from jaxrbf import InputError, _tune, objectives
from jaxrbf._tune import support_floor
from jaxrbf.cli import main

P, N = sphere(100)


def test_loocv_matches_brute_force():
    x = np.random.default_rng(3).random((40, 3))
    y = np.sin(3 * x[:, 0]) + x[:, 1]
    fast = objectives.loocv_error(x, values=y, kernel="gaussian", radius=0.5, residuals=True)
    errors = []
    for i in range(len(x)):
        keep = np.arange(len(x)) != i
        m = jaxrbf.fit(x[keep], y[keep], kernel="gaussian", radius=0.5)
        errors.append((y[i] - float(m(x[i : i + 1])[0])) / np.abs(y).max())
    np.testing.assert_allclose(np.asarray(fast) * np.sqrt(len(x)), errors, rtol=1e-6, atol=1e-9)


@pytest.mark.slow
def test_held_out_and_kfold():
    a = objectives.held_out_error(P, N, kernel="cubic", offset=0.05)
    assert 0 < float(a) < 0.2  # a sphere's held-out samples lie close to the fitted zero set
    # a wrong normal on the held-out side shows up in the misalignment term
    train, test = objectives.split_samples(len(P), 0.2, 0)
    flipped = N.copy()
    flipped[test[:5]] *= -1
    worse = objectives.held_out_error(P, flipped, kernel="cubic", offset=0.05, test=test)
    assert float(worse) > float(a) + 5 * 2 / len(test) * 0.9
    k = objectives.kfold_error(P, N, kernel="cubic", offset=0.05, k=2)
    folds = np.array_split(np.random.default_rng(0).permutation(len(P)), 2)
    each = [
        float(objectives.held_out_error(P, N, kernel="cubic", offset=0.05, test=np.sort(f)))
        for f in folds
    ]
    assert float(k) == pytest.approx(np.mean(each), rel=1e-10)


@pytest.mark.slow
def test_objective_gradients_match_finite_differences():
    f = lambda a: objectives.held_out_error(  # noqa: E731
        P, N, kernel="gaussian", offset=a[0], radius=a[1]
    )
    a = np.array([0.05, 0.4])
    g = np.asarray(jax.jacfwd(f)(jnp.asarray(a)))
    for k in range(2):
        e = np.zeros(2)
        e[k] = 1e-6
        fd = (float(f(a + e)) - float(f(a - e))) / 2e-6
        assert g[k] == pytest.approx(fd, rel=1e-4, abs=1e-7)


@pytest.mark.slow
@pytest.mark.parametrize(
    "kernel, names, background",
    [
        ("gaussian", ("offset", "radius"), False),
        ("gaussian", ("offset", "radius"), True),
        ("wendland", ("offset", "radius", "smoothing"), False),
        ("cubic", ("offset",), False),
        ("thin-plate", ("offset", "smoothing"), False),
    ],
)
def test_adjoint_value_and_grad_matches_forward_mode(kernel, names, background):
    # the hand-written adjoint gradient (closed-form kernel derivatives, one LU for fit and
    # adjoint) against forward mode through held_out_error, with offsets clipped at some caps
    # (and, for the Gaussian, over the background of the training samples or without one)
    start = {"offset": 0.08, "radius": 0.6, "smoothing": 1e-6}
    base = {k: jnp.asarray(v) for k, v in start.items()}
    y = {k: jnp.log(start[k]) for k in names}
    lo = {k: jnp.asarray(v - 3.0) for k, v in y.items()}
    hi = {k: jnp.asarray(v + 3.0) for k, v in y.items()}
    data = objectives.held_out_data(P, N, background=background)
    assert (data.background is not None) == background
    use_radius = kernel in ("gaussian", "wendland")

    def direct(y):
        v = {k: jnp.exp(y[k]) if k in y else base[k] for k in start}
        return objectives.held_out_error(
            P,
            N,
            kernel=kernel,
            offset=v["offset"],
            radius=v["radius"] if use_radius else None,
            smoothing=v["smoothing"],
            background=background,
        )

    f, g, ok = objectives.held_out_value_and_grad(y, lo, hi, base, data, kernel=kernel)
    assert bool(ok)
    assert float(f) == pytest.approx(float(direct(y)), rel=1e-10)
    ref = jax.jacfwd(direct)(y)
    for k in names:
        assert float(g[k]) == pytest.approx(float(ref[k]), rel=1e-6, abs=1e-9), k
    assert max(abs(float(g[k])) for k in names) > 1e-4
    # the value alone (tune's last step) is the same value
    f1, g1, _ = objectives.held_out_value_and_grad(
        y, lo, hi, base, data, kernel=kernel, gradient=False
    )
    assert float(f1) == pytest.approx(float(f), rel=1e-12)
    assert all(float(g1[k]) == 0.0 for k in names)
    # outside its bounds a parameter is clipped: the objective is flat in it
    y_out = dict(y, offset=y["offset"] + 5.0)
    f2, g2, _ = objectives.held_out_value_and_grad(y_out, lo, hi, base, data, kernel=kernel)
    assert float(g2["offset"]) == 0.0
    y_edge = dict(y, offset=hi["offset"])
    assert float(f2) == pytest.approx(float(direct(y_edge)), rel=1e-10)


@pytest.mark.slow
def test_tune_fast_path_follows_forward_mode():
    # tune's held-out objective (adjoint gradient, one compiled function cached across calls)
    # and the same objective as a user function (forward mode, compiled per call) take the same
    # BFGS path
    def mine(points, normals, **kw):
        return objectives.held_out_error(points, normals, **kw)

    _, fast = jaxrbf.tune(P, N, kernel="gaussian", radius=0.25, max_steps=3)
    _, slow = jaxrbf.tune(P, N, kernel="gaussian", radius=0.25, max_steps=3, objective=mine)
    assert slow.objective == "mine" and fast.objective == "held-out"
    # over the Gaussian's background: the start and its offset x2 and x4 first, then 2 steps
    assert len(fast.path) == len(slow.path) == 5
    tol = 1e-3 * fast.path[0]["objective"]  # near-exact fits: objective values to rounding
    for a, b in zip(fast.path, slow.path, strict=True):
        assert a["objective"] == pytest.approx(b["objective"], abs=tol)
        for k in ("offset", "radius"):
            assert a[k] == pytest.approx(b[k], rel=1e-5), k
    assert fast.path[-1]["offset"] != pytest.approx(fast.path[0]["offset"], rel=1e-3)


@pytest.mark.slow
def test_tune_improves_and_reports():
    model, report = jaxrbf.tune(P, N, kernel="gaussian", radius=0.25, max_steps=4)
    assert isinstance(model, jaxrbf.RBFModel)
    assert report.final_objective <= report.initial_objective
    assert report.params == ("offset", "radius")
    # the start and its offset scaled by OFFSET_SCAN first (over the background), then the steps
    assert len(report.path) == report.iterations + 1 + len(_tune.OFFSET_SCAN)
    assert report.iterations == 3
    assert report.path[0]["objective"] == pytest.approx(report.initial_objective)
    for entry, factor in zip(report.path[1:], _tune.OFFSET_SCAN, strict=False):
        assert entry["offset"] == pytest.approx(factor * report.initial["offset"])
    # the report's final objective is the objective at the final parameters
    assert report.background  # a Gaussian fits over a background by default
    again = objectives.held_out_error(
        P,
        N,
        kernel="gaussian",
        offset=report.final["offset"],
        radius=report.final["radius"],
        background=True,
    )
    assert float(again) == pytest.approx(report.final_objective, rel=1e-3, abs=1e-6)
    # kept because it beats the start by more than one standard error, which was measured
    assert report.improved and np.isfinite(report.standard_error)
    assert report.initial_objective - report.final_objective > report.standard_error
    # the model is fitted with them and interpolates the surface
    assert np.abs(np.asarray(model(P))).max() < 1e-6
    assert "tune (BFGS" in report.summary()


def test_tune_with_levenberg_marquardt_offset_only():
    lm = optx.LevenbergMarquardt(rtol=1e-3, atol=1e-3)
    _, report = jaxrbf.tune(P, N, kernel="cubic", params=("offset",), solver=lm, max_steps=3)
    assert report.final_objective <= report.initial_objective
    assert set(report.final) == {"offset"}


def test_tune_never_returns_worse_than_the_start():
    # an objective whose minimum is the start: nothing better exists, the start comes back
    d0 = 0.05

    def bowl(points, normals, *, offset, **_):
        return (jnp.log(offset) - np.log(d0)) ** 2 + 1.0

    _, report = jaxrbf.tune(P, N, kernel="cubic", params="offset", offset=d0, objective=bowl)
    assert not report.improved
    assert report.final["offset"] == d0  # the start itself, not exp(log(d0))
    assert report.final_objective == report.initial_objective
    assert "start is returned" in report.message


def test_grid_search():
    offsets, radii = [0.03, 0.06], [0.2, 0.4]
    best, table, _ = jaxrbf.grid_search(P, N, kernel="wendland", offsets=offsets, radii=radii)
    assert table.shape == (2, 2) and np.all(np.isfinite(table))
    i, j = np.unravel_index(np.argmin(table), table.shape)
    assert (best["offset"], best["radius"]) == (offsets[i], radii[j])
    direct = objectives.held_out_error(P, N, kernel="wendland", offset=0.06, radius=0.4)
    assert table[1, 1] == pytest.approx(float(direct), rel=1e-10)


def test_defaults_follow_the_point_spacing():
    r1 = jaxrbf.default_radius("gaussian", P)
    assert r1 == pytest.approx(1.75 * objectives.point_spacing(P))
    assert jaxrbf.default_radius("gaussian", 10 * P) == pytest.approx(10 * r1)
    assert jaxrbf.default_radius("cubic", P) is None
    assert jaxrbf.default_offset(10 * P) == pytest.approx(10 * jaxrbf.default_offset(P))


def test_wendland_support_covers_the_box():
    # Samples of a sphere: the farthest points of their box grown by 5% are its corners.
    floor = support_floor(P)
    lo, hi = P.min(axis=0), P.max(axis=0)
    pad = 0.05 * (hi - lo)
    corners = np.array([[a, b, c] for a in (0, 1) for b in (0, 1) for c in (0, 1)])
    corners = np.where(corners, hi + pad, lo - pad)
    expected = np.linalg.norm(corners[:, None] - P[None], axis=-1).min(axis=1).max()
    assert expected <= floor <= 1.05 * expected
    # tuning a Wendland fit never searches below it, even from a smaller start
    _, report = jaxrbf.tune(P, N, kernel="wendland", radius=0.2, max_steps=2)
    assert report.initial["radius"] == pytest.approx(floor)
    assert all(step["radius"] >= floor * (1 - 1e-9) for step in report.path)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(params=("size",)), "unknown parameter 'size'"),
        (dict(kernel="cubic", params=("radius",)), "cubic kernel has no radius to tune"),
        (dict(offset=-1.0), "`offset` must be a positive number"),
        (dict(kernel="gaussian", radius=0.0), "`radius` must be a positive number"),
        (dict(params=("offset", "smoothing")), "start the smoothing at a small positive"),
        (dict(objective="best"), "unknown objective 'best'"),
        (dict(solver=optx.Bisection(rtol=1e-3, atol=1e-3)), "optimistix minimiser"),
        (dict(max_steps=0), "`max_steps` must be at least 1"),
    ],
)
def test_tune_input_errors(kwargs, match):
    with pytest.raises(InputError, match=match):
        jaxrbf.tune(P, N, **kwargs)


def test_tune_rejects_nan_points():
    bad = P.copy()
    bad[2, 1] = np.nan
    with pytest.raises(InputError, match="NaN"):
        jaxrbf.tune(bad, N)


def test_shape_fitting_by_gradient_descent():
    """The documented use: RBF values as the parameters of a shape, fitted with optimistix to
    signed-distance samples of another shape (a sphere of radius 1.3)."""
    c = jaxrbf.Constraints.from_points(*sphere(40), 0.2)
    rng = np.random.default_rng(5)
    q = rng.normal(size=(300, 3))
    q *= rng.uniform(1.0, 1.6, size=(300, 1)) / np.linalg.norm(q, axis=1, keepdims=True)
    target = sphere_sdf(q, 1.3)

    def loss(values, args):
        model = jaxrbf.fit(c.points, values, kernel="cubic", solver="lu")
        return jnp.mean((model(q) - target) ** 2)

    v0 = jnp.asarray(c.values)  # the unit sphere's own signed distances
    start = float(loss(v0, None))
    sol = optx.minimise(loss, optx.BFGS(rtol=1e-8, atol=1e-8), v0, max_steps=60, throw=False)
    assert float(loss(sol.value, None)) < 0.05 * start


def test_tune_command(tmp_path, capsys):
    out = tmp_path / "m.npz"
    code = main(["tune", "--example", "bunny", "-o", str(out), "--points", "200", "-q"])
    text, err = capsys.readouterr()
    assert code == 0, err
    assert "initial:" in text and "final:" in text and "step 0" in text
    model = jaxrbf.load(out)
    assert isinstance(model, jaxrbf.RBFModel)
    code = main(["tune", "--example", "bunny", "-o", str(tmp_path / "x.npz"), "--params", "radius"])
    _, err = capsys.readouterr()
    assert code == 2 and "jaxrbf: error:" in err and "no radius" in err
    assert not (tmp_path / "x.npz").exists()


def test_reconstruct_tune(tmp_path, capsys):
    src = tmp_path / "ball.xyz"
    np.savetxt(src, np.hstack([P, N]))
    out = tmp_path / "ball.ply"
    args = ["reconstruct", str(src), "-o", str(out), "--tune", "--resolution", "32"]
    code = main(args + ["--kernel", "wendland"])
    _, err = capsys.readouterr()
    assert code == 0, err
    assert "tune (BFGS" in err
    v = jaxrbf.io.read_mesh(out).vertices
    assert np.abs(np.linalg.norm(v, axis=1) - 1).max() < 0.03
    code = main(args + ["--solver", "cg", "-o", str(tmp_path / "y.ply")])
    _, err = capsys.readouterr()
    assert code == 2 and "--tune fits one dense system" in err


def test_rescaled_state_matches_a_restart():
    # tune divides the objective by a scale chosen after the first step; rescaling the solver's
    # state must give the same next steps as restarting BFGS with that scale (which pays one more
    # evaluation of the start).
    from jaxrbf._tune import _rescaled

    def fn(y, args):
        return (
            jnp.sum((y - jnp.array([1.0, -2.0])) ** 2 * jnp.array([3.0, 0.5])) + 1.0
        ) / args, None

    solver = optx.BFGS(rtol=1e-8, atol=1e-8)
    y0 = jnp.array([0.3, 0.4])
    opts, tags = {"autodiff_mode": "fwd"}, frozenset()
    f_struct = jax.ShapeDtypeStruct((), jnp.float64)
    st = solver.init(fn, y0, 1.0, opts, f_struct, None, tags)
    y, st, _ = solver.step(fn, y0, 1.0, opts, st, tags)
    scale = jnp.asarray(7.0)
    fast = _rescaled(st, y, scale)
    assert fast is not None
    slow = solver.init(fn, y0, scale, opts, f_struct, None, tags)
    ys, slow, _ = solver.step(fn, y0, scale, opts, slow, tags)
    yf = y
    for _ in range(3):
        yf, fast, _ = solver.step(fn, yf, scale, opts, fast, tags)
        ys, slow, _ = solver.step(fn, ys, scale, opts, slow, tags)
        np.testing.assert_allclose(yf, ys, rtol=1e-12, atol=1e-14)
    assert not np.allclose(yf, y0)


def test_one_standard_error_rule():
    # paired per-sample errors: a small mean improvement with a large spread is within one
    # standard error (the start is kept), a consistent one is not
    a = np.random.default_rng(0).uniform(0.5, 1.5, 400)
    sign = np.tile([1.0, -1.0], 200)
    noisy = a - 0.01 + 0.5 * sign  # mean improvement 0.01, standard error 0.025
    steady = a - 0.01 + 0.001 * sign  # the same improvement, standard error 5e-5
    for b, kept in ((noisy, True), (steady, False)):
        evaluated = [(float(a.mean()), a), (float(b.mean()), b)]
        se = _tune._standard_error(evaluated, float(a.mean()), float(b.mean()))
        assert se == pytest.approx(np.std(a - b, ddof=1) / 20.0)
        assert (a.mean() - b.mean() <= se) == kept
    # nothing recorded for one of them (another objective): not measured
    assert np.isnan(_tune._standard_error([(1.0, a)], 1.0, 0.5))
