import jax.numpy as jnp
import numpy as np
import pytest
from helpers import ellipse, euler, signed_volume, sphere, torus, torus_sdf

import jaxrbf
from jaxrbf import Constraints, InputError


def test_analytic_sphere_any_callable():
    mesh = jaxrbf.polygonize(
        lambda p: jnp.linalg.norm(p, axis=-1) - 1.0, resolution=40, bounds=((-1.3,) * 3, (1.3,) * 3)
    )
    assert np.abs(np.linalg.norm(mesh.vertices, axis=1) - 1).max() < 5e-3
    assert signed_volume(mesh) == pytest.approx(4 / 3 * np.pi, rel=0.02)  # > 0: faces outward
    assert euler(mesh) == 2


def test_sphere_recovered_from_points():
    p, n = sphere(300)
    model = jaxrbf.fit(Constraints.from_points(p, n, offset=0.05))
    mesh = jaxrbf.polygonize(model, resolution=48)
    assert np.abs(np.linalg.norm(mesh.vertices, axis=1) - 1).max() < 0.01
    assert signed_volume(mesh) == pytest.approx(4 / 3 * np.pi, rel=0.02)
    assert euler(mesh) == 2


def test_torus_recovered_from_points():
    p, n = torus()
    model = jaxrbf.fit(Constraints.from_points(p, n, offset=0.05))
    mesh = jaxrbf.polygonize(model, resolution=64)
    assert np.abs(torus_sdf(mesh.vertices)).max() < 0.02
    assert signed_volume(mesh) == pytest.approx(2 * np.pi**2 * 1.0 * 0.35**2, rel=0.03)
    assert euler(mesh) == 0  # genus one


def test_projection_moves_vertices_onto_the_surface():
    p, n = sphere(200)
    model = jaxrbf.fit(Constraints.from_points(p, n, offset=0.05))
    rough = jaxrbf.polygonize(model, resolution=16)
    fine = jaxrbf.polygonize(model, resolution=16, project=True)
    assert np.abs(np.asarray(model(fine.vertices))).max() < 1e-8
    assert np.abs(np.asarray(model(rough.vertices))).max() > 1e-4
    np.testing.assert_array_equal(rough.faces, fine.faces)


def test_project_reports_convergence():
    f = lambda q: jnp.linalg.norm(q, axis=-1) - 1.0  # noqa: E731
    start = np.array([[2.0, 0.0, 0.0], [0.0, 0.5, 0.5], [0.0, 0.0, 0.0]])
    moved, ok = jaxrbf.project(f, start, steps=20, max_step=0.5)
    np.testing.assert_allclose(np.linalg.norm(moved[:2], axis=1), 1.0, atol=1e-9)
    assert ok.tolist() == [True, True, False]  # the centre has no gradient direction


def test_level_sets():
    f = lambda q: jnp.linalg.norm(q, axis=-1)  # noqa: E731
    mesh = jaxrbf.polygonize(f, resolution=40, bounds=((-1,) * 3, (1,) * 3), level=0.5)
    assert np.abs(np.linalg.norm(mesh.vertices, axis=1) - 0.5).max() < 5e-3


def test_contour_of_a_polyline_fit():
    v = ellipse(50)
    model = jaxrbf.fit(Constraints.from_polyline(v, closed=True, offset=0.05), kernel="thin-plate")
    curves = jaxrbf.contour(model, resolution=200)
    assert len(curves) == 1
    c = curves[0]
    np.testing.assert_allclose(c[0], c[-1])  # closed
    assert np.abs((c[:, 0] / 2) ** 2 + c[:, 1] ** 2 - 1).max() < 0.02
    inner = jaxrbf.contour(model, resolution=200, level=-0.03)
    assert np.abs(inner[0]).max() < np.abs(c).max()


def test_errors():
    with pytest.raises(InputError, match="`bounds` is needed"):
        jaxrbf.polygonize(lambda q: q[:, 0])
    with pytest.raises(InputError, match="never crosses level 0"):
        jaxrbf.polygonize(lambda q: jnp.ones(q.shape[0]), resolution=8, bounds=((0,) * 3, (1,) * 3))
    with pytest.raises(InputError, match="NaN or infinite values at"):
        jaxrbf.polygonize(lambda q: jnp.log(q[:, 0]), resolution=8, bounds=((-1,) * 3, (1,) * 3))
    with pytest.raises(InputError, match="hi > lo"):
        jaxrbf.polygonize(lambda q: q[:, 0], resolution=8, bounds=((0,) * 3, (0,) * 3))
    with pytest.raises(InputError, match="at least 2 samples"):
        jaxrbf.polygonize(lambda q: q[:, 0], resolution=1, bounds=((0,) * 3, (1,) * 3))


def test_components_with_no_sample_near_are_dropped():
    """Of a mesh of three spheres, the one with no input sample on it goes (a surface no input
    stands behind); the small one that holds a few samples stays."""
    from jaxrbf._polygonize import drop_unsupported

    def f(x):
        d1 = jnp.linalg.norm(x, axis=-1) - 1.0
        d2 = jnp.linalg.norm(x - jnp.array([2.0, 0.0, 0.0]), axis=-1) - 0.3
        d3 = jnp.linalg.norm(x - jnp.array([0.0, 2.0, 0.0]), axis=-1) - 0.3
        return jnp.minimum(jnp.minimum(d1, d2), d3)

    mesh = jaxrbf.polygonize(f, resolution=64, bounds=([-1.5] * 3, [2.5] * 3))
    big, _ = sphere(2000)
    small, _ = sphere(12, 0.3, (2.0, 0.0, 0.0))
    samples = np.concatenate([big, small])
    spacing = 0.05
    out = drop_unsupported(mesh, samples, spacing)
    v = np.asarray(out.vertices)
    assert len(out.faces) < len(mesh.faces)
    assert np.all(np.linalg.norm(v - [0.0, 2.0, 0.0], axis=1) > 0.5)  # the bare sphere went
    assert np.any(np.linalg.norm(v - [2.0, 0.0, 0.0], axis=1) < 0.5)  # the sampled one stayed
    # a grid cell coarser than the samples' spacing widens the reach by its diagonal: with a
    # cell of 0.5 (reach 0.87) the bare sphere, 0.7 from the big one's samples, stays
    assert len(drop_unsupported(mesh, samples, spacing, cell=0.5).faces) == len(mesh.faces)
    assert len(drop_unsupported(mesh, samples, spacing, cell=0.3).faces) < len(mesh.faces)
    # nothing is supported: the mesh is left for the accounts check to refuse
    far, _ = sphere(50, 1.0, (10.0, 10.0, 10.0))
    assert len(drop_unsupported(mesh, far, spacing).faces) == len(mesh.faces)
    # a bubble that one or two samples alone stand behind (a stray point) goes too; three stay
    for k, stays in ((1, False), (2, False), (3, True)):
        lone = np.array([[0.0, 2.0, 0.0]]) + 0.3 * np.eye(3)[:k]  # on the bare sphere
        v = np.asarray(drop_unsupported(mesh, np.concatenate([samples, lone]), spacing).vertices)
        assert np.any(np.linalg.norm(v - [0.0, 2.0, 0.0], axis=1) < 0.5) == stays
