"""Backgrounds of surface fits with decaying kernels (`jaxrbf.surface_background`,
`fit(..., background=...)`): the model adds them, the fit reproduces its constraints through
them, they keep the sign right far from the data, they survive save/load, and gradients flow."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import fd_gradient, sphere, torus, torus_sdf

import jaxrbf
from jaxrbf import InputError

P, N = torus()
C = jaxrbf.Constraints.from_points(P, N, 0.05)
BG = jaxrbf.surface_background(P, N)


def _probes():
    """Points of the torus's box at least 0.12 from its surface, and the side they lie on."""
    q = np.random.default_rng(0).uniform(-1.6, 1.6, (4000, 3)) * np.array([1.0, 1.0, 0.5])
    s = torus_sdf(q)
    far = np.abs(s) > 0.12
    return q[far], np.sign(s[far])


def test_surface_background_is_a_coarse_polyharmonic_fit():
    assert isinstance(BG, jaxrbf.RBFModel) and BG.kernel.name == "cubic"
    # every sample when there are fewer than BACKGROUND_MIN, with its two off-surface points
    assert BG.centres.shape[0] <= 3 * len(P)
    # it is near zero on the surface and has the right sign off it
    assert float(jnp.max(jnp.abs(BG(P)))) < 0.05
    q, side = _probes()
    assert np.all(np.sign(np.asarray(BG(q))) == side)
    # built once per set of samples
    assert jaxrbf.surface_background(P, N) is BG
    p2, n2 = sphere(40)
    assert jaxrbf.surface_background(p2, n2).centres.shape[1] == 3


def test_model_adds_the_background_and_its_gradient():
    model = jaxrbf.fit(C, kernel="gaussian", radius=0.2, background=BG)
    assert model.background is BG
    bare = eqx.tree_at(lambda m: m.background, model, None, is_leaf=lambda x: x is None)
    x = np.random.default_rng(1).uniform(-1.3, 1.3, (50, 3))
    np.testing.assert_allclose(model(x), bare(x) + BG(x), rtol=1e-12, atol=1e-12)
    f, g = model.value_and_gradient(x)
    np.testing.assert_allclose(f, model(x), rtol=1e-12, atol=1e-12)
    for i in range(5):
        fd = fd_gradient(lambda y: model(y), x[i])
        np.testing.assert_allclose(g[i], fd, rtol=1e-5, atol=1e-6)
    # through the constraints: the RBF part was fitted to the values minus the background
    np.testing.assert_allclose(model(C.points), C.values, atol=1e-8)
    assert float(model.residual) < 1e-8


def test_background_keeps_the_sign_right_far_from_the_data():
    # a Gaussian of small radius is its bare polynomial between the torus's sheets and far
    # outside: a plane whose zero crossing is a spurious sheet. Over the background it is not.
    q, side = _probes()
    plain = jaxrbf.fit(C, kernel="gaussian", radius=0.1)
    over = jaxrbf.fit(C, kernel="gaussian", radius=0.1, background=BG)
    wrong_plain = np.mean(np.sign(np.asarray(plain(q))) != side)
    wrong_over = np.mean(np.sign(np.asarray(over(q))) != side)
    assert wrong_over == 0.0
    assert wrong_plain > 0.01  # the failure the background is there for


def test_save_and_load_keep_the_background(tmp_path):
    model = jaxrbf.fit(C, kernel="gaussian", radius=0.2, background=BG)
    path = tmp_path / "m.npz"
    jaxrbf.save(model, path)
    assert int(np.load(path)["format_version"]) == 2
    back = jaxrbf.load(path)
    assert isinstance(back.background, jaxrbf.RBFModel)
    x = np.random.default_rng(2).uniform(-1.3, 1.3, (20, 3))
    np.testing.assert_allclose(back(x), model(x), rtol=1e-12, atol=1e-12)
    # a model without one is still written in format 1, which older versions read
    jaxrbf.save(jaxrbf.fit(C, kernel="cubic"), path)
    assert int(np.load(path)["format_version"]) == 1
    # a file whose background is cut short names the problem
    jaxrbf.save(model, path)
    d = dict(np.load(path))
    del d["bg.weights"]
    np.savez(tmp_path / "bad.npz", **d)
    with pytest.raises(InputError, match="bg.weights"):
        jaxrbf.load(tmp_path / "bad.npz")


def test_background_errors_name_the_problem():
    with pytest.raises(InputError, match="background"):
        jaxrbf.fit(C, kernel="gaussian", radius=0.2, background="yes")
    p2 = np.random.default_rng(0).random((30, 2))
    with pytest.raises(InputError, match="3-D model but the points are 2-D"):
        jaxrbf.fit(p2, np.arange(30.0), kernel="gaussian", radius=0.2, background=BG)
    with pytest.raises(InputError, match="method='dense'"):
        jaxrbf.fit(C, kernel="gaussian", radius=0.2, background=BG, method="partition")
    # the traced path checks it the same way
    with pytest.raises(InputError, match="method='dense'"):
        jax.grad(
            lambda r: jnp.sum(
                jaxrbf.fit(C, kernel="gaussian", radius=r, background=BG, method="partition")(P)
            )
        )(0.2)
    with pytest.raises(InputError, match="one normal per point"):
        jaxrbf.surface_background(P, N[:10])


def test_gradient_flows_through_a_fit_over_a_background():
    x = np.random.default_rng(3).uniform(-1.2, 1.2, (10, 3))

    def loss(log_r):
        m = jaxrbf.fit(C, kernel="gaussian", radius=jnp.exp(log_r), background=BG)
        return jnp.sum(m(x) ** 2)

    a = jnp.log(0.2)
    g = float(jax.grad(loss)(a))
    fd = (float(loss(a + 1e-5)) - float(loss(a - 1e-5))) / 2e-5
    assert g == pytest.approx(fd, rel=1e-4)
    assert abs(g) > 1e-6


@pytest.mark.slow
def test_surface_paths_add_it_for_decaying_kernels_only():
    # tune (its objective, its final fit) and fit_surface put a Gaussian fit over the
    # background of the samples by default, and its far field has the right sign; a cubic or
    # Wendland fit (which covers the box by itself) gets none unless asked
    q, side = _probes()
    model, report = jaxrbf.tune(P, N, kernel="gaussian", radius=0.1, max_steps=2)
    assert report.background and "over a background" in report.summary()
    assert model.background is not None
    assert np.mean(np.sign(np.asarray(model(q))) != side) == 0.0
    model, report = jaxrbf.tune(P, N, kernel="gaussian", radius=0.1, max_steps=2, background=False)
    assert not report.background and model.background is None
    model, report = jaxrbf.tune(P, N, kernel="cubic", max_steps=2)
    assert not report.background and model.background is None
    over = jaxrbf.fit_surface(P, N, kernel="gaussian", method="dense")
    assert over.background is not None
    assert np.mean(np.sign(np.asarray(over(q))) != side) == 0.0
    assert jaxrbf.fit_surface(P, N, kernel="wendland", method="dense").background is None
    # the held-out objective's background comes from the training samples alone
    data = jaxrbf.objectives.held_out_data(P, N, background=True)
    assert data.background is not None and data.background is not jaxrbf.surface_background(P, N)
    with pytest.raises(InputError, match="`background` must be 'auto', True or False"):
        jaxrbf.tune(P, N, kernel="gaussian", background="yes")
