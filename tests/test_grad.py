"""Differentiable fitting: gradients of `fit` against central finite differences, for the dense
path (LU and Cholesky, under jax.grad and jax.jit) and the partition-of-unity path."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import sphere, torus

import jaxrbf
from jaxrbf import InputError, SolveError, _difffit, _partition
from jaxrbf.kernels import Wendland

P, N = sphere(60)
Q = np.random.default_rng(0).normal(size=(25, 3)) * 0.7
CAPS = jaxrbf.offset_caps(P, N, 0.5)


def _fd(f, x, h):
    x = np.asarray(x, dtype=float)
    g = np.zeros_like(x)
    for k in range(x.size):
        e = np.zeros_like(x)
        e.flat[k] = h
        g.flat[k] = (float(f(x + e)) - float(f(x - e))) / (2 * h)
    return g


def _loss(offset, radius, smoothing, points=P, normals=N, solver="lu", kernel="gaussian"):
    c = jaxrbf.surface_constraints(points, normals, offset, CAPS)
    radius = None if kernel == "cubic" else radius
    model = jaxrbf.fit(
        c, kernel=kernel, radius=radius, smoothing=smoothing, solver=solver, method="dense"
    )
    return jnp.sum(model(Q) ** 2) + jnp.sum(model.gradient(Q[:5]) ** 2)


@pytest.mark.slow
@pytest.mark.parametrize("solver", ["lu", "cholesky"])
def test_dense_gradients_match_finite_differences(solver):
    args = (0.1, 0.7, 1e-4)
    g = jax.grad(lambda a: _loss(*a, solver=solver))(jnp.asarray(args))
    fd = _fd(lambda a: _loss(*a, solver=solver), args, np.array([1e-6, 1e-6, 1e-8]).max())
    # smoothing needs a smaller step than the others: check it on its own
    fd[2] = _fd(lambda s: _loss(0.1, 0.7, s[0], solver=solver), [1e-4], 1e-8)[0]
    np.testing.assert_allclose(np.asarray(g), fd, rtol=1e-5, atol=1e-8)
    assert np.all(np.abs(np.asarray(g)) > 1e-6)  # every parameter actually moves the loss


@pytest.mark.slow
def test_gradients_wrt_points_normals_and_values():
    idx = (3, 1)  # one coordinate of one surface point, and of its normal

    def by_point(v):
        pts = jnp.asarray(P).at[idx].set(v)
        return _loss(0.1, 0.7, 0.0, points=pts, kernel="cubic", solver="lu")

    def by_normal(v):
        nrm = jnp.asarray(N).at[idx].set(v)
        return _loss(0.1, 0.7, 0.0, normals=nrm, kernel="cubic", solver="lu")

    for fn, x0 in ((by_point, P[idx]), (by_normal, N[idx])):
        g = float(jax.grad(fn)(x0))
        fd = _fd(lambda v, fn=fn: fn(v[0]), [x0], 1e-4)[
            0
        ]  # the loss is ~10: larger steps, less noise
        assert g == pytest.approx(fd, rel=1e-4, abs=1e-9)
        assert abs(g) > 1e-8

    c = jaxrbf.Constraints.from_points(P, N, 0.1)

    def by_values(h):
        return jnp.sum(jaxrbf.fit(c.points, h, solver="lu")(Q) ** 2)

    h0 = np.asarray(c.values)
    g = np.asarray(jax.grad(by_values)(h0))
    for k in (0, 70, 150):
        e = np.zeros_like(h0)
        e[k] = 1e-6
        fd = (float(by_values(h0 + e)) - float(by_values(h0 - e))) / 2e-6
        assert g[k] == pytest.approx(fd, rel=1e-5, abs=1e-9)


def test_jit_gives_the_same_values_and_gradients():
    f = lambda a: _loss(a[0], a[1], 0.0)  # noqa: E731
    a = jnp.asarray([0.1, 0.7])
    v1, g1 = jax.value_and_grad(f)(a)
    v2, g2 = jax.jit(jax.value_and_grad(f))(a)
    np.testing.assert_allclose(float(v1), float(v2), rtol=1e-10)
    np.testing.assert_allclose(np.asarray(g1), np.asarray(g2), rtol=1e-8)


def test_traced_fit_matches_host_fit():
    c = jaxrbf.Constraints.from_points(P, N, 0.1, validate=False)
    host = jaxrbf.fit(c, kernel="wendland", radius=1.5, solver="lu")
    traced = jax.jit(lambda r: jaxrbf.fit(c, kernel="wendland", radius=r, solver="lu")(Q))(1.5)
    np.testing.assert_allclose(np.asarray(traced), np.asarray(host(Q)), atol=1e-10)


def test_traced_errors():
    c = jaxrbf.Constraints.from_points(P, N, 0.1)
    with pytest.raises(InputError, match="not available under jax.grad"):
        jax.grad(lambda h: jnp.sum(jaxrbf.fit(c.points, h, solver="cg").weights))(c.values)
    with pytest.raises(InputError, match="greedy centre selection.*not differentiable"):
        jax.grad(lambda h: jnp.sum(jaxrbf.fit(c.points, h, method="global").weights))(c.values)
    # a Gaussian as wide as the shape: numerically singular, reported under grad too
    with pytest.raises(SolveError, match="reproduce its constraints|singular"):
        jax.grad(lambda r: jnp.sum(jaxrbf.fit(c, kernel="gaussian", radius=r)(Q)))(30.0)


@pytest.fixture(scope="module")
def torus_constraints():
    p, n = torus(28, 10)
    return jaxrbf.Constraints.from_points(p, n, 0.05)


@pytest.mark.slow
def test_partition_gradients(torus_constraints, monkeypatch):
    monkeypatch.setattr(_partition, "BASE_SIZE", 250)
    c = torus_constraints
    q = np.random.default_rng(1).normal(size=(30, 3)) * 0.6

    def loss(radius, value_scale):
        m = jaxrbf.fit(
            c.points,
            c.values * value_scale,
            kernel="wendland",
            radius=radius,
            method="partition",
        )
        return jnp.sum(m(q) ** 2)

    g = jax.grad(loss, argnums=(0, 1))(1.0, 1.0)
    fd_r = (float(loss(1.0 + 1e-5, 1.0)) - float(loss(1.0 - 1e-5, 1.0))) / 2e-5
    fd_s = (float(loss(1.0, 1.0 + 1e-5)) - float(loss(1.0, 1.0 - 1e-5))) / 2e-5
    assert float(g[0]) == pytest.approx(fd_r, rel=1e-4)
    assert float(g[1]) == pytest.approx(fd_s, rel=1e-4)
    # the traced partition model is the host one
    host = jaxrbf.fit(c, kernel="wendland", radius=1.0, method="partition")
    traced = _difffit.fit_partition_traced(c.points, c.values, Wendland(1.0), 1, 0.0)
    assert isinstance(host, jaxrbf.PartitionModel) and host.n_patches == traced.n_patches
    np.testing.assert_allclose(np.asarray(traced(q)), np.asarray(host(q)), atol=1e-9)
    # gradients with respect to the points would need the layout to move: refused
    with pytest.raises(InputError, match="not the constraint points"):
        jax.grad(lambda x: jnp.sum(jaxrbf.fit(x, c.values, method="partition", kernel="cubic")(q)))(
            c.points
        )
