import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import fd_gradient, sphere

import jaxrbf
from jaxrbf import Constraints, InputError
from jaxrbf._model import block_rows


@pytest.fixture(scope="module")
def sphere_model():
    p, n = sphere(200)
    return jaxrbf.fit(Constraints.from_points(p, n, offset=0.05))


@pytest.fixture(scope="module")
def gauss_model():
    x = np.random.default_rng(0).random((150, 3))
    return jaxrbf.fit(x, np.cos(4 * x[:, 0]) * x[:, 1], kernel="gaussian", radius=0.3)


@pytest.mark.parametrize("which", ["sphere_model", "gauss_model"])
def test_gradient_matches_finite_differences(which, request):
    model = request.getfixturevalue(which)
    pts = np.random.default_rng(1).uniform(-0.9, 0.9, (5, 3))
    g = np.asarray(model.gradient(pts))
    for p, gp in zip(pts, g, strict=True):
        np.testing.assert_allclose(gp, fd_gradient(lambda y: model(y), p), rtol=1e-5, atol=1e-7)


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(jaxrbf.kernels.KERNELS))
@pytest.mark.parametrize("degree", [0, 1])
def test_analytic_gradient_matches_autodiff(name, degree):
    # value_and_gradient is written by hand for RBF models (the kernel's derivative in r^2, then
    # one product with [w, w c]); reverse-mode autodiff of the values is the reference.
    rng = np.random.default_rng(2)
    x = rng.random((60, 3))
    kern = jaxrbf.kernels.make_kernel(
        name, 0.5 if jaxrbf.kernels.KERNELS[name].has_radius else None
    )
    degree = max(degree, kern.min_degree)
    model = jaxrbf.fit(x, np.sin(3 * x[:, 0]) + x[:, 2], kernel=kern, degree=degree, verbose=False)
    pts = jnp.asarray(np.concatenate([rng.uniform(-0.2, 1.2, (40, 3)), x[:3]]))
    f, g = model.value_and_gradient(pts)
    ref = jax.vmap(jax.grad(lambda y: model(y[None])[0]))(pts)
    np.testing.assert_allclose(f, model(pts), rtol=1e-12, atol=1e-12)
    scale = float(jnp.max(jnp.abs(ref)))
    np.testing.assert_allclose(g, ref, rtol=1e-7, atol=1e-9 * scale)
    assert np.all(np.isfinite(g))


def test_gradient_finite_at_centres(sphere_model):
    g = np.asarray(
        sphere_model.gradient(
            np.asarray(sphere_model.centres[:10] * sphere_model.scale + sphere_model.shift)
        )
    )
    assert np.all(np.isfinite(g))


def test_sign_along_normals(sphere_model):
    p, n = sphere(50)
    for t in (0.02, 0.1, 0.3):
        assert np.all(np.asarray(sphere_model(p + t * n)) > 0)
        assert np.all(np.asarray(sphere_model(p - t * n)) < 0)
    assert float(sphere_model(np.zeros(3))) < 0
    assert float(sphere_model(np.array([3.0, 0, 0]))) > 0


def test_normals_point_outward(sphere_model):
    p, n = sphere(40)
    got = np.asarray(sphere_model.normal(p))
    assert np.min(np.sum(got * n, axis=1)) > 0.99
    np.testing.assert_allclose(np.linalg.norm(got, axis=1), 1.0, atol=1e-12)


def test_shapes_and_chunking(sphere_model):
    pts = np.random.default_rng(2).uniform(
        -1, 1, (3 * block_rows(sphere_model.centres.shape[0]) + 7, 3)
    )
    full = np.asarray(sphere_model(pts))
    pieces = np.concatenate(
        [np.asarray(sphere_model(pts[i : i + 50])) for i in range(0, len(pts), 50)]
    )
    np.testing.assert_allclose(full, pieces, rtol=1e-12, atol=1e-12)
    assert sphere_model(pts.reshape(-1, 1, 3)[:12].reshape(3, 4, 3)).shape == (3, 4)
    assert sphere_model(np.zeros(3)).shape == ()
    assert sphere_model.gradient(pts[:6].reshape(2, 3, 3)).shape == (2, 3, 3)


def test_jit_vmap_grad(sphere_model):
    pts = jnp.asarray(np.random.default_rng(3).uniform(-1, 1, (20, 3)))
    direct = sphere_model(pts)
    np.testing.assert_allclose(jax.jit(lambda m, x: m(x))(sphere_model, pts), direct, rtol=1e-12)
    np.testing.assert_allclose(jax.vmap(sphere_model)(pts), direct, rtol=1e-12)
    g = jax.vmap(jax.grad(sphere_model))(pts)
    np.testing.assert_allclose(g, sphere_model.gradient(pts), rtol=1e-10)
    # gradients with respect to the model's own leaves (weights) flow as well
    gw = jax.grad(lambda m: jnp.sum(m(pts)))(sphere_model).weights
    assert gw.shape == sphere_model.weights.shape and bool(jnp.all(jnp.isfinite(gw)))


def test_wrong_dimension(sphere_model):
    with pytest.raises(ValueError, match=r"shape \(\.\.\., 3\)"):
        sphere_model(np.zeros((4, 2)))


def test_save_load_identity(sphere_model, tmp_path):
    path = tmp_path / "m.npz"
    jaxrbf.save(sphere_model, path)
    back = jaxrbf.load(path)
    pts = np.random.default_rng(4).uniform(-1, 1, (30, 3))
    np.testing.assert_array_equal(np.asarray(back(pts)), np.asarray(sphere_model(pts)))
    assert back.kernel.name == sphere_model.kernel.name and back.degree == sphere_model.degree
    assert float(back.residual) == float(sphere_model.residual)


def test_save_load_radius_kernel(gauss_model, tmp_path):
    jaxrbf.save(gauss_model, tmp_path / "g.npz")
    back = jaxrbf.load(tmp_path / "g.npz")
    assert float(back.kernel.radius) == float(gauss_model.kernel.radius)
    x = np.random.default_rng(5).random((10, 3))
    np.testing.assert_array_equal(np.asarray(back(x)), np.asarray(gauss_model(x)))


def test_load_errors(sphere_model, tmp_path):
    with pytest.raises(InputError, match="does not exist"):
        jaxrbf.load(tmp_path / "nope.npz")
    good = tmp_path / "good.npz"
    jaxrbf.save(sphere_model, good)
    cut = tmp_path / "cut.npz"
    cut.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    with pytest.raises(InputError, match="truncated or corrupt"):
        jaxrbf.load(cut)
    foreign = tmp_path / "foreign.npz"
    np.savez(foreign, a=np.ones(3))
    with pytest.raises(InputError, match="is not a jaxrbf model"):
        jaxrbf.load(foreign)
    with np.load(good) as z:
        d = dict(z)
    d["format_version"] = np.array(99)
    newer = tmp_path / "newer.npz"
    np.savez(newer, **d)
    with pytest.raises(InputError, match="newer than this jaxrbf reads"):
        jaxrbf.load(newer)
    d["format_version"] = np.array(1)
    d["weights"] = d["weights"][:-1]
    np.savez(newer, **d)
    with pytest.raises(InputError, match="inconsistent array shapes"):
        jaxrbf.load(newer)
    empty = tmp_path / "empty.npz"
    empty.write_bytes(b"")
    with pytest.raises(InputError, match="truncated or corrupt"):
        jaxrbf.load(empty)


def test_save_is_atomic(sphere_model, tmp_path, monkeypatch):
    path = tmp_path / "m.npz"
    path.write_bytes(b"precious")

    def boom(*a, **k):
        raise RuntimeError("disk full")

    monkeypatch.setattr(np, "savez", boom)
    with pytest.raises(RuntimeError, match="disk full"):
        jaxrbf.save(sphere_model, path)
    assert path.read_bytes() == b"precious"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.npz"]


def test_save_load_fit_keeps_the_samples_and_walls(sphere_model, tmp_path):
    """`save(..., samples=, normals=, walls=, shells=)` round-trips through `load_fit`; a file saved
    without them gives None and empty walls; bad arrays are refused on save and on load."""
    rng = np.random.default_rng(2)
    p, n = rng.normal(size=(40, 3)), rng.normal(size=(40, 3))
    walls = (rng.normal(size=(5, 3)), rng.normal(size=(5, 3)))
    shells = (rng.normal(size=(7, 3)), rng.normal(size=(7, 3)))
    path = tmp_path / "fit.npz"
    jaxrbf.save(sphere_model, path, samples=p, normals=n, walls=walls, shells=shells)
    model, points, normals = fitted = jaxrbf.load_fit(path)
    np.testing.assert_array_equal(points, p)
    np.testing.assert_array_equal(normals, n)
    np.testing.assert_array_equal(fitted.walls[0], walls[0])
    np.testing.assert_array_equal(fitted.walls[1], walls[1])
    np.testing.assert_array_equal(fitted.shells[0], shells[0])
    np.testing.assert_array_equal(fitted.shells[1], shells[1])
    x = rng.uniform(-1, 1, (8, 3))
    np.testing.assert_array_equal(np.asarray(model(x)), np.asarray(sphere_model(x)))

    bare = tmp_path / "bare.npz"
    jaxrbf.save(sphere_model, bare)
    _, points, normals = fitted = jaxrbf.load_fit(bare)
    assert points is None and normals is None and fitted.walls[0].shape == (0, 3)
    assert fitted.shells[0].shape == (0, 3)

    with pytest.raises(InputError, match=r"`samples` must have shape \(n, 3\)"):
        jaxrbf.save(sphere_model, path, samples=p[:, :2])
    with pytest.raises(InputError, match="NaN or infinite"):
        jaxrbf.save(sphere_model, path, samples=np.where(p > 2, np.nan, p))
    with pytest.raises(InputError, match="one row per sample"):
        jaxrbf.save(sphere_model, path, samples=p, normals=n[:-1])
    with pytest.raises(InputError, match="pass `samples` too"):
        jaxrbf.save(sphere_model, path, walls=walls)
    with pytest.raises(InputError, match="pass `samples` too"):
        jaxrbf.save(sphere_model, path, shells=shells)
    with pytest.raises(InputError, match="`shells` must be"):
        jaxrbf.save(sphere_model, path, samples=p, shells=(shells[0], shells[1][:-1]))
    with np.load(path) as z:
        d = dict(z)
    d["walls.normals"] = d["walls.normals"][:-1]
    np.savez(tmp_path / "bad.npz", **d)
    with pytest.raises(InputError, match="damaged.*walls.normals"):
        jaxrbf.load_fit(tmp_path / "bad.npz")
