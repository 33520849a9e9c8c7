import jax.numpy as jnp
import numpy as np
import pytest
from helpers import euler, signed_volume, sphere

import jaxrbf
from jaxrbf import Constraints, InputError
from jaxrbf import _polygonize as poly

BOX = ((-1.3,) * 3, (1.3,) * 3)


def ball(q):
    return jnp.linalg.norm(q, axis=-1) - 1.0


def ring(q):
    return jnp.hypot(jnp.linalg.norm(q[:, :2], axis=-1) - 1.0, q[:, 2]) - 0.35


def twins(q):  # two balls 0.04 apart: under two fine cells at these resolutions
    shift = jnp.array([0.52, 0.0, 0.0])
    return (
        jnp.minimum(jnp.linalg.norm(q - shift, axis=-1), jnp.linalg.norm(q + shift, axis=-1)) - 0.5
    )


def shell(q):  # a sphere 0.03 thick: about one fine cell
    return jnp.abs(jnp.linalg.norm(q, axis=-1) - 1.0) - 0.015


def canonical_faces(faces):
    """Each face rotated to start at its smallest index (orientation kept), rows sorted."""
    first = np.argmin(faces, axis=1)
    rolled = np.stack([np.roll(f, -k) for f, k in zip(faces, first, strict=True)])
    return rolled[np.lexsort(rolled.T[::-1])]


def assert_same_mesh(dense, band):
    assert len(band.vertices) == len(dense.vertices)
    assert len(band.faces) == len(dense.faces)
    assert euler(band) == euler(dense)
    order_d = np.lexsort(dense.vertices.T[::-1])
    order_b = np.lexsort(band.vertices.T[::-1])
    np.testing.assert_allclose(band.vertices[order_b], dense.vertices[order_d], rtol=0, atol=1e-9)
    rank_d, rank_b = np.empty_like(order_d), np.empty_like(order_b)
    rank_d[order_d] = np.arange(len(order_d))
    rank_b[order_b] = np.arange(len(order_b))
    np.testing.assert_array_equal(
        canonical_faces(rank_b[band.faces]), canonical_faces(rank_d[dense.faces])
    )


@pytest.mark.slow
@pytest.mark.parametrize(
    "f, bounds, resolution, genus",
    [
        (ball, BOX, 96, 0),
        (ring, ((-1.5, -1.5, -0.5), (1.5, 1.5, 0.5)), 83, 1),  # 82 cells: not a multiple of 8
        (twins, ((-1.2, -0.7, -0.7), (1.2, 0.7, 0.7)), 96, None),
        (shell, BOX, 96, None),
    ],
    ids=["sphere", "torus", "two-close-spheres", "thin-shell"],
)
@pytest.mark.parametrize("coarsening", [8, 2])
def test_band_equals_dense_on_analytic_shapes(f, bounds, resolution, genus, coarsening):
    dense = jaxrbf.polygonize(f, resolution, bounds, narrow_band=False)
    band = jaxrbf.polygonize(f, resolution, bounds, narrow_band=True, coarsening=coarsening)
    assert_same_mesh(dense, band)
    if genus is not None:
        assert euler(band) == 2 - 2 * genus
    stats = poly.last_band_stats()
    if coarsening == 2:  # cells of one fine cell: a thin band, many samples skipped
        assert stats.cell == 1 and stats.band_samples < 0.6 * stats.grid_samples


def test_band_equals_dense_on_a_fitted_model():
    p, n = sphere(300)
    model = jaxrbf.fit(Constraints.from_points(p, n, offset=0.05), kernel="cubic", solver="lu")
    dense = jaxrbf.polygonize(model, resolution=80, narrow_band=False)
    band = jaxrbf.polygonize(model, resolution=80, narrow_band=True, coarsening=4)
    assert_same_mesh(dense, band)
    assert euler(band) == 2
    assert signed_volume(band) == pytest.approx(4 / 3 * np.pi, rel=0.02)


def test_band_grows_with_the_area_not_the_volume():
    bounds = ((-1.5,) * 3, (1.5,) * 3)
    counts = {}
    for res in (96, 128, 192, 256):
        idx, shape = poly.band_samples(ball, res, bounds)
        assert np.all(np.diff(idx) > 0) and idx[0] >= 0 and idx[-1] < np.prod(shape)
        counts[res] = len(idx)
    assert 3.0 < counts[192] / counts[96] < 5.0  # a volume would give 8
    assert 3.0 < counts[256] / counts[128] < 5.0
    assert counts[256] < 0.25 * 256**3
    # polygonize evaluates exactly these samples, and the coarse levels' gradient samples
    mesh = jaxrbf.polygonize(ball, 128, bounds, narrow_band=True)
    stats = poly.last_band_stats()
    assert stats.band_samples == counts[128] and stats.grid_samples == 128**3
    assert stats.evaluated == stats.band_samples + stats.gradient_samples
    assert stats.gradient_samples < 0.02 * stats.grid_samples
    assert euler(mesh) == 2


def test_band_orientation_projection_level_and_bounds():
    band = jaxrbf.polygonize(ball, 100, BOX, narrow_band=True, coarsening=4)
    assert signed_volume(band) == pytest.approx(4 / 3 * np.pi, rel=0.02)  # > 0: outward
    projected = jaxrbf.polygonize(ball, 100, BOX, narrow_band=True, coarsening=4, project=True)
    np.testing.assert_array_equal(projected.faces, band.faces)
    assert np.abs(np.linalg.norm(projected.vertices, axis=1) - 1).max() < 1e-8
    assert np.abs(np.linalg.norm(band.vertices, axis=1) - 1).max() > 1e-5

    def dist(q):
        return jnp.linalg.norm(q, axis=-1)

    half = jaxrbf.polygonize(dist, 90, ((-1,) * 3, (1,) * 3), level=0.5, narrow_band=True)
    assert np.abs(np.linalg.norm(half.vertices, axis=1) - 0.5).max() < 5e-3
    assert signed_volume(half) > 0
    # a box that cuts the sphere: the open mesh stays inside it, as in the dense path
    lo, hi = (0.0, -1.2, -1.2), (1.2, 1.2, 1.2)
    cut = jaxrbf.polygonize(ball, 90, (lo, hi), narrow_band=True, coarsening=4)
    assert np.all(cut.vertices >= np.array(lo) - 1e-12) and np.all(cut.vertices <= hi)
    assert_same_mesh(jaxrbf.polygonize(ball, 90, (lo, hi), narrow_band=False), cut)


def test_band_errors():
    def flat(q):
        return jnp.ones(q.shape[0])

    def bowl(q):  # a minimum of 1e-3 at the origin: near the level, never across it
        return jnp.sum(q * q, axis=-1) + 1e-3

    for f in (flat, bowl):
        with pytest.raises(InputError, match="never crosses level 0"):
            jaxrbf.polygonize(f, 40, BOX, narrow_band=True, coarsening=4)
    with pytest.raises(InputError, match="NaN or infinite values at"):
        jaxrbf.polygonize(lambda q: jnp.log(q[:, 0]), 40, BOX, narrow_band=True)
    with pytest.raises(InputError, match="`coarsening` must be an integer >= 1"):
        jaxrbf.polygonize(ball, 40, BOX, narrow_band=True, coarsening=0)
    with pytest.raises(InputError, match="`refine` must be an integer >= 0"):
        jaxrbf.polygonize(ball, 40, BOX, narrow_band=True, refine=-1)
    with pytest.raises(InputError, match="`band_width` must be a positive number"):
        jaxrbf.polygonize(ball, 40, BOX, narrow_band=True, band_width=0)


def test_dense_grid_refused_when_memory_is_short(monkeypatch):
    monkeypatch.setattr(poly, "_available_memory", lambda: 2**20)
    with pytest.raises(InputError, match=r"needs about .* GiB .* use narrow_band=True"):
        jaxrbf.polygonize(ball, 64, BOX, narrow_band=False)
    mesh = jaxrbf.polygonize(ball, 64, BOX, narrow_band=True)  # the band needs no full grid
    assert euler(mesh) == 2


def test_automatic_rule_and_progress_line(monkeypatch, capsys):
    monkeypatch.setattr(poly, "_last_stats", None)
    jaxrbf.polygonize(ball, 160, BOX, progress=False)
    assert poly.last_band_stats() is None  # 160 samples: dense
    jaxrbf.polygonize(ball, 161, BOX, progress=True)
    stats = poly.last_band_stats()
    assert stats is not None and stats.shape == (161, 161, 161)
    err = capsys.readouterr().err
    assert f"narrow band: {100 * stats.fraction:.1f}% of 4.17M grid samples evaluated" in err
