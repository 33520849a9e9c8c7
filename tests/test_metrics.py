"""Surface metrics against shapes with known answers."""

from pathlib import Path

import numpy as np
import pytest

from jaxrbf import io, metrics
from jaxrbf._errors import InputError

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data"
N = 50_000


@pytest.fixture(scope="module")
def sphere():
    import trimesh

    s = trimesh.creation.icosphere(subdivisions=4)
    return io.Mesh(s.vertices, s.faces)


def _square(x0=0.0, angle=0.0):
    """A unit square in the plane z = 0 starting at x = x0, tilted by `angle` about the x axis."""
    c, s = np.cos(angle), np.sin(angle)
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], dtype=float)
    v = v @ np.array([[1, 0, 0], [0, c, s], [0, -s, c]])
    v[:, 0] += x0
    return v, np.array([[0, 1, 2], [0, 2, 3]])


def test_sample_surface_uniform_and_on_faces():
    v, f = _square()
    v = v * [2.0, 1.0, 1.0]  # 2 x 1 rectangle
    p, n = metrics.sample_surface((v, f), 20_000, seed=3)
    assert p.shape == (20_000, 3) and n.shape == (20_000, 3)
    np.testing.assert_allclose(n, np.tile([0, 0, 1], (20_000, 1)))
    assert np.all((p[:, 0] >= 0) & (p[:, 0] <= 2) & (p[:, 1] >= 0) & (p[:, 1] <= 1))
    assert abs(p[:, 2]).max() == 0
    # Uniform on [0,2]x[0,1]: mean (1, 0.5); left half holds half the points.
    np.testing.assert_allclose(p[:, :2].mean(0), [1.0, 0.5], atol=0.02)
    assert np.mean(p[:, 0] < 1) == pytest.approx(0.5, abs=0.02)
    # Deterministic in the seed.
    np.testing.assert_array_equal(
        metrics.sample_surface((v, f), 10, seed=3)[0], metrics.sample_surface((v, f), 10, seed=3)[0]
    )
    assert not np.array_equal(
        metrics.sample_surface((v, f), 10, seed=3)[0], metrics.sample_surface((v, f), 10, seed=4)[0]
    )


def test_sample_surface_area_weighting():
    """Two triangles with areas 1 : 3 get samples in that ratio."""
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 2, 0], [5, 0, 0], [8, 0, 0], [5, 2, 0]], dtype=float)
    f = np.array([[0, 1, 2], [3, 4, 5]])
    p, _ = metrics.sample_surface((v, f), 40_000)
    assert np.mean(p[:, 0] < 2) == pytest.approx(0.25, abs=0.01)


def test_mesh_against_itself(sphere):
    r = metrics.evaluate(sphere, sphere, n=N)
    assert r["chamfer_l1"] < 1e-3 and r["hausdorff"] < 1e-3
    assert r["f_score"] == 1.0
    assert r["normal_consistency"] > 0.99


@pytest.mark.skipif(not DATA.exists(), reason="the shared test meshes (../shared/data) are absent")
def test_spot_against_itself_reordered():
    """Same surface, other face order, so independent samples: only sampling noise remains.

    For uniform random points of density n / A on a surface, the mean distance to the nearest
    point of another such sample is 0.5 * sqrt(A / n) (planar Poisson process).
    """
    m = io.read_mesh(DATA / "spot.obj")
    tri = m.vertices[m.faces]
    area = (
        0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).sum()
    )
    diag = np.linalg.norm(m.vertices.max(0) - m.vertices.min(0))
    perm = np.random.default_rng(0).permutation(len(m.faces))
    r = metrics.evaluate(io.Mesh(m.vertices, m.faces[perm]), m, n=N)
    assert r["chamfer_l1"] == pytest.approx(0.5 * np.sqrt(area / N) / diag, rel=0.05)
    assert r["normal_consistency"] > 0.99
    assert r["f_score"] == 1.0


def test_scaled_sphere(sphere):
    diag = 2 * np.sqrt(3)
    big = io.Mesh(sphere.vertices * 1.01, sphere.faces)
    expected = 0.01 / diag
    assert metrics.chamfer_l1(big, sphere, n=N) == pytest.approx(expected, rel=0.1)
    assert metrics.hausdorff(big, sphere, n=N) == pytest.approx(expected, rel=0.1)
    # Below the gap nothing matches; above it everything does.
    assert metrics.f_score(big, sphere, threshold=0.5 * expected, n=N) < 0.01
    assert metrics.f_score(big, sphere, threshold=2.0 * expected, n=N) == 1.0
    # Normalised by the reference: the same gap measured against the big sphere is smaller.
    assert metrics.chamfer_l1(sphere, big, n=N) == pytest.approx(expected / 1.01, rel=0.1)


def test_evaluate_matches_single_metrics(sphere):
    big = (sphere.vertices * 1.02, sphere.faces)  # a (vertices, faces) pair works too
    r = metrics.evaluate(big, sphere, n=N, seed=5, threshold=0.004)
    assert set(r) == {"chamfer_l1", "hausdorff", "normal_consistency", "f_score", "threshold"}
    assert r["threshold"] == 0.004
    assert r["chamfer_l1"] == metrics.chamfer_l1(big, sphere, n=N, seed=5)
    assert r["hausdorff"] == metrics.hausdorff(big, sphere, n=N, seed=5)
    assert r["normal_consistency"] == metrics.normal_consistency(big, sphere, n=N, seed=5)
    assert r["f_score"] == metrics.f_score(big, sphere, threshold=0.004, n=N, seed=5)
    assert all(isinstance(x, float) for x in r.values())


def test_normal_consistency_tilted_plane():
    """Two unit squares 30 degrees apart: every pair of normals has |cos| = cos 30."""
    flat, tilted = _square(), _square(angle=np.pi / 6)
    nc = metrics.normal_consistency(tilted, flat, n=5_000)
    assert nc == pytest.approx(np.cos(np.pi / 6), abs=1e-9)
    # Flipped orientation does not matter.
    v, f = flat
    assert metrics.normal_consistency((v, f[:, ::-1]), flat, n=5_000) == pytest.approx(1.0)


def test_f_score_partial_surface():
    """pred covers one of ref's two equal squares: precision 1, recall 1/2, F = 2/3."""
    (va, fa), (vb, fb) = _square(0.0), _square(10.0)
    ref = (np.vstack([va, vb]), np.vstack([fa, fb + 4]))
    r = metrics.evaluate((va, fa), ref, n=N)
    assert r["f_score"] == pytest.approx(2 / 3, abs=0.01)
    # Hausdorff: the far square's far corner is ~10 + sqrt(2) from pred; diag(ref) = sqrt(122).
    assert r["hausdorff"] == pytest.approx(np.hypot(10, 1) / np.sqrt(122), rel=0.02)


def test_errors(sphere):
    v = sphere.vertices
    with pytest.raises(InputError, match="`pred` has no faces"):
        metrics.evaluate(io.Mesh(v, np.zeros((0, 3), dtype=np.int64)), sphere, n=100)
    with pytest.raises(InputError, match="`ref` has no faces"):
        metrics.chamfer_l1(sphere, (v, []), n=100)
    with pytest.raises(InputError, match="`mesh` has no faces"):
        metrics.sample_surface((v, np.zeros((0, 3), dtype=int)), 10)
    with pytest.raises(InputError, match="zero surface area"):
        metrics.sample_surface((np.zeros((3, 3)), [[0, 1, 2]]), 10)
    with pytest.raises(InputError, match="must be a jaxrbf.io.Mesh"):
        metrics.evaluate("mesh.obj", sphere)
    with pytest.raises(InputError, match="threshold"):
        metrics.f_score(sphere, sphere, threshold=0)
    with pytest.raises(InputError, match="faces refer to vertices"):
        metrics.hausdorff((v, sphere.faces + len(v)), sphere, n=100)
