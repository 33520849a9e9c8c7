"""Primitives and CSG: values and gradients against their definitions, transforms, bounds, and
use by polygonize, the metrics and jit."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import fd_gradient, sphere, torus_sdf

import jaxrbf
from jaxrbf import csg

RNG = np.random.default_rng(0)
X3 = RNG.uniform(-1.6, 1.6, (200, 3))


def box_sdf(x, c, h):
    q = np.abs(x - c) - h
    return np.linalg.norm(np.maximum(q, 0), axis=-1) + np.minimum(q.max(axis=-1), 0)


def test_primitive_values_match_closed_forms():
    np.testing.assert_allclose(
        csg.Sphere((0.1, 0.2, 0.3), 0.7)(X3),
        np.linalg.norm(X3 - (0.1, 0.2, 0.3), axis=1) - 0.7,
        atol=1e-14,
    )
    c, h = np.array([0.1, -0.2, 0.0]), np.array([0.5, 0.8, 0.3])
    np.testing.assert_allclose(csg.Box(c, h)(X3), box_sdf(X3, c, h), atol=1e-14)
    np.testing.assert_allclose(csg.Torus((0, 0, 0), 1.0, 0.35)(X3), torus_sdf(X3), atol=1e-14)
    cyl = csg.Cylinder((0, 0, 0.1), 0.6, 0.9)
    radial = np.linalg.norm(X3[:, :2], axis=1) - 0.6
    axial = np.abs(X3[:, 2] - 0.1) - 0.9
    q = np.stack([radial, axial], 1)
    expect = np.linalg.norm(np.maximum(q, 0), axis=1) + np.minimum(q.max(1), 0)
    np.testing.assert_allclose(cyl(X3), expect, atol=1e-14)
    np.testing.assert_allclose(csg.Cylinder(radius=0.6, half_height=None)(X3), radial, atol=1e-14)
    plane = csg.Plane((0, 0, 2.0), 0.5)
    np.testing.assert_allclose(plane(X3), X3[:, 2] - 0.5, atol=1e-14)
    # shapes of (..., d) inputs are kept
    assert csg.Sphere()(X3.reshape(10, 20, 3)).shape == (10, 20)
    # 2-D shapes
    x2 = X3[:, :2]
    np.testing.assert_allclose(
        csg.Box((0, 0), (1, 0.5))(x2), box_sdf(x2, np.zeros(2), np.array([1, 0.5]))
    )


SHAPES = {
    "sphere": csg.Sphere((0.1, 0.0, 0.0), 0.8),
    "box": csg.Box((0, 0, 0), (0.6, 0.5, 0.4)),
    "torus": csg.Torus((0, 0, 0), 0.9, 0.3),
    "cylinder": csg.Cylinder((0, 0, 0), 0.5, 0.7),
    "union": csg.Union(csg.Sphere((0.3, 0, 0), 0.6), csg.Box((-0.3, 0, 0), (0.4, 0.4, 0.4))),
    "smooth union": csg.Union(
        csg.Sphere((0.3, 0, 0), 0.6), csg.Sphere((-0.4, 0, 0), 0.5), radius=0.3
    ),
    "smooth intersection": csg.Intersection(
        csg.Box((0, 0, 0), (0.6, 0.6, 0.6)), csg.Sphere((0, 0, 0), 0.75), radius=0.2
    ),
    "smooth difference": csg.Difference(
        csg.Box((0, 0, 0), (0.6, 0.6, 0.6)), csg.Cylinder((0, 0, 0), 0.3, 1.0), radius=0.1
    ),
    "rotated torus": csg.rotate(csg.Torus((0, 0, 0), 0.9, 0.3), (1, 0, 0), 90),
    "affine": csg.Affine(
        csg.Sphere(), [[1.0, 0.3, 0.0], [0.0, 0.8, 0.0], [0.0, 0.0, 1.2]], (0.1, 0, 0)
    ),
    "offset": csg.Offset(csg.Box((0, 0, 0), (0.4, 0.4, 0.4)), 0.2),
}


@pytest.mark.parametrize("name", list(SHAPES))
def test_gradients_match_finite_differences(name):
    shape = SHAPES[name]
    g = np.asarray(shape.gradient(X3[:25]))
    for x, gx in zip(X3[:25], g, strict=True):
        np.testing.assert_allclose(gx, fd_gradient(lambda y: shape(y[None])[0], x), atol=2e-6)
    n = np.asarray(shape.normal(X3[:25]))
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-12)


def test_boolean_values_are_min_max_and_smooth_variants_are_bounded():
    a, b = csg.Sphere((0.3, 0, 0), 0.6), csg.Box((-0.3, 0, 0), (0.4, 0.4, 0.4))
    fa, fb = np.asarray(a(X3)), np.asarray(b(X3))
    np.testing.assert_array_equal((a | b)(X3), np.minimum(fa, fb))
    np.testing.assert_array_equal((a & b)(X3), np.maximum(fa, fb))
    np.testing.assert_array_equal((a - b)(X3), np.maximum(fa, -fb))
    np.testing.assert_array_equal((-a)(X3), -fa)
    r = 0.25
    su = np.asarray(csg.Union(a, b, radius=r)(X3))
    si = np.asarray(csg.Intersection(a, b, radius=r)(X3))
    sd = np.asarray(csg.Difference(a, b, radius=r)(X3))
    far = np.abs(fa - fb) >= r
    np.testing.assert_allclose(su[far], np.minimum(fa, fb)[far], atol=1e-15)
    assert np.all(su <= np.minimum(fa, fb) + 1e-15) and np.all(su >= np.minimum(fa, fb) - r / 4)
    assert np.all(si >= np.maximum(fa, fb) - 1e-15) and np.all(si <= np.maximum(fa, fb) + r / 4)
    assert np.all(sd >= np.maximum(fa, -fb) - 1e-15)
    # hard min: the gradient is the active child's
    ga, gb = np.asarray(a.gradient(X3)), np.asarray(b.gradient(X3))
    np.testing.assert_allclose((a | b).gradient(X3), np.where((fa < fb)[:, None], ga, gb))
    # three children
    c = csg.Sphere((0, 0.5, 0), 0.3)
    np.testing.assert_array_equal(csg.Union(a, b, c)(X3), np.minimum(np.minimum(fa, fb), c(X3)))


def test_transforms():
    t = csg.Torus((0, 0, 0), 0.9, 0.3)
    rotated = csg.rotate(t, (1, 0, 0), 90)  # the torus's axis z goes to -y
    swapped = X3[:, [0, 2, 1]] * np.array([1, 1, -1])
    np.testing.assert_allclose(rotated(X3), t(swapped), atol=1e-12)
    big = csg.scale(csg.Sphere((0, 0, 0), 1.0), 1.5)
    np.testing.assert_allclose(big(X3), np.linalg.norm(X3, axis=1) - 1.5, atol=1e-12)
    moved = csg.translate(csg.Sphere((0, 0, 0), 1.0), (0.2, 0.3, -0.1))
    np.testing.assert_allclose(
        moved(X3), np.linalg.norm(X3 - (0.2, 0.3, -0.1), axis=1) - 1, atol=1e-12
    )
    lo, hi = moved.bounds()
    np.testing.assert_allclose(lo, [-0.8, -0.7, -1.1])
    np.testing.assert_allclose(hi, [1.2, 1.3, 0.9])
    # a non-uniform map keeps the zero set and stays a lower bound of the distance
    squash = csg.scale(csg.Sphere((0, 0, 0), 1.0), (2.0, 1.0, 1.0))
    p = np.array([[2.0, 0, 0], [0, 1.0, 0], [3.0, 0, 0]])
    np.testing.assert_allclose(squash(p)[:2], 0, atol=1e-12)
    assert 0 < float(squash(p)[2]) <= 1.0
    with pytest.raises(jaxrbf.InputError, match="invertible"):
        csg.Affine(csg.Sphere(), np.zeros((3, 3)))
    np.testing.assert_allclose(
        csg.Offset(csg.Sphere(), 0.25)(X3), np.linalg.norm(X3, axis=1) - 1.25
    )


def test_bounds_of_csg():
    a, b = csg.Sphere((0, 0, 0), 1.0), csg.Box((1, 0, 0), (0.5, 0.5, 0.5))
    np.testing.assert_allclose((a | b).bounds()[1], [1.5, 1, 1])
    np.testing.assert_allclose((a & b).bounds()[0], [0.5, -0.5, -0.5])
    np.testing.assert_allclose((a - b).bounds()[0], [-1, -1, -1])
    half = csg.Intersection(a, csg.Plane((0, 0, 1), 0.2))
    np.testing.assert_allclose(half.bounds()[1], [1, 1, 0.2])
    assert np.all(np.isinf(csg.Plane((1, 1, 0), 0).bounds()[0]))


def test_polygonize_metrics_and_jit():
    shape = csg.Box((0, 0, 0), (0.6, 0.6, 0.6)) - csg.Sphere((0, 0, 0), 0.75)
    mesh = jaxrbf.polygonize(shape, resolution=48)
    ball = jaxrbf.polygonize(csg.Sphere((0, 0, 0), 0.75), resolution=48)
    # the cut-outs are spherical caps of the ball: the two surfaces share them
    assert jaxrbf.metrics.chamfer_l1(mesh, mesh) == 0
    assert 0 < jaxrbf.metrics.chamfer_l1(mesh, ball, n=20_000) < 0.1
    assert np.abs(np.asarray(shape(mesh.vertices))).max() < 0.02
    # volume: box minus ball (the ball pokes out through the faces)
    from helpers import signed_volume

    r, a = 0.75, 0.6
    cap = np.pi * (r - a) ** 2 * (3 * r - (r - a)) / 3
    exact = (2 * a) ** 3 - (4 / 3 * np.pi * r**3 - 6 * cap)
    assert abs(signed_volume(mesh) - exact) < 0.08 * exact  # marching cubes cuts the edges
    # jit over the shape (a pytree), and derivatives with respect to its parameters
    f = jax.jit(lambda s, x: s(x))
    np.testing.assert_allclose(f(shape, X3), shape(X3))
    d_radius = jax.grad(lambda s: jnp.sum(s(X3[:1])))(csg.Sphere((0, 0, 0), 0.5))
    assert float(d_radius.radius) == -1.0


def test_csg_with_a_fitted_model():
    p, n = sphere(150, radius=0.5)
    model = jaxrbf.fit(jaxrbf.Constraints.from_points(p, n), kernel="cubic")
    bite = model - csg.Sphere((0.5, 0, 0), 0.3)
    x = np.array([[0.5, 0.0, 0.0], p[np.argmin(p[:, 0])], [0.0, 0.0, 0.0]])
    v = np.asarray(bite(x))
    assert v[0] > 0.05  # carved out
    assert abs(v[1]) < 1e-8 and v[2] < 0  # a constraint of the model, away from the bite
    lo, hi = bite.bounds()
    np.testing.assert_allclose(hi, np.asarray(model.bounds()[1]))
    assert np.all(np.isfinite(np.asarray(bite.gradient(x))))


def test_bad_shapes():
    with pytest.raises(jaxrbf.InputError, match="radius"):
        csg.Sphere((0, 0, 0), -1)
    with pytest.raises(jaxrbf.InputError, match="half_size"):
        csg.Box((0, 0, 0), (1, 0, 1))
    with pytest.raises(jaxrbf.InputError, match="dimension"):
        csg.Union(csg.Sphere((0, 0)), csg.Sphere((0, 0, 0)))
    with pytest.raises(jaxrbf.InputError, match="at least two"):
        csg.Union(csg.Sphere())
    with pytest.raises(jaxrbf.InputError, match="non-zero"):
        csg.Plane((0, 0, 0))
    with pytest.raises(jaxrbf.InputError, match="finite"):
        csg.Sphere((np.nan, 0, 0))
    with pytest.raises(jaxrbf.InputError, match=r"\(\.\.\., 3\)"):
        csg.Sphere()(np.zeros((4, 2)))
    with pytest.raises(jaxrbf.InputError, match="finite"):
        jaxrbf.polygonize(csg.Plane(), resolution=8)
