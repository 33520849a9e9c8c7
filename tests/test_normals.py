"""Normal estimation for bare point clouds: PCA + minimum-spanning-tree orientation."""

import numpy as np
import pytest
from helpers import sphere

import jaxrbf
from jaxrbf.cli import main


def ellipsoid(n=3000, axes=(1.0, 0.6, 0.35), noise=0.0, seed=0):
    """Points on an ellipsoid with true outward normals; `noise` is a fraction of the diagonal."""
    p, nrm = sphere(n)
    a = np.asarray(axes)
    q = p * a
    true = nrm / a
    true /= np.linalg.norm(true, axis=1, keepdims=True)
    diag = 2 * np.linalg.norm(a)
    q = q + noise * diag * np.random.default_rng(seed).standard_normal(q.shape)
    return q, true


def thin_box(n=4000, size=(1.0, 1.0, 0.1), seed=0):
    """Uniform points on the surface of a box (a thin plate by default) with outward normals."""
    rng = np.random.default_rng(seed)
    s = np.asarray(size)
    area = np.array([s[1] * s[2], s[0] * s[2], s[0] * s[1]]).repeat(2)
    face = rng.choice(6, n, p=area / area.sum())
    p = (rng.random((n, 3)) - 0.5) * s
    axis, side = face // 2, np.where(face % 2 == 0, -1.0, 1.0)
    rows = np.arange(n)
    p[rows, axis] = side * s[axis] / 2
    true = np.zeros((n, 3))
    true[rows, axis] = side
    return p, true


def _scores(est, true):
    dot = np.einsum("ij,ij->i", est, true)
    angle = np.degrees(np.arccos(np.clip(np.abs(dot), 0, 1)))
    return float(np.mean(dot < 0)), float(np.mean(angle))


def test_sphere_and_ellipsoid_normals_match_the_true_ones():
    for p, true in (sphere(2000), ellipsoid(3000)):
        est, rep = jaxrbf.estimate_normals(p)
        assert est.shape == p.shape
        np.testing.assert_allclose(np.linalg.norm(est, axis=1), 1.0, atol=1e-12)
        wrong, angle = _scores(est, true)
        assert wrong < 0.01 and angle < 2.0, (wrong, angle)
        assert rep.components == 1 and rep.k == jaxrbf._normals.default_k(len(p))
        assert 0.0 <= rep.flipped <= 1.0 and rep.unsure < 0.01 * len(p)


def test_orientation_is_outward_whatever_the_pca_sign():
    # A sphere's normals reversed on input order must not matter: every normal points outward.
    p, true = sphere(1500)
    est, _ = jaxrbf.estimate_normals(p[::-1], k=12)
    assert np.all(np.einsum("ij,ij->i", est, true[::-1]) > 0.9)


def test_noisy_ellipsoid_orients_correctly():
    p, true = ellipsoid(4000, noise=0.005)
    est, rep = jaxrbf.estimate_normals(p)
    wrong, angle = _scores(est, true)
    assert wrong < 0.01 and angle < 10.0, (wrong, angle, rep)


def test_thin_plate_orients_both_faces():
    # 0.1 thick, about 4.5 point spacings: a kNN graph with plain weights 1 - |n.n| links the two
    # faces, whose normals are anti-parallel.
    p, true = thin_box(4000, (1.0, 1.0, 0.1))
    est, rep = jaxrbf.estimate_normals(p)
    wrong, _ = _scores(est, true)
    assert wrong < 0.01, (wrong, rep)
    faces = np.abs(true[:, 2]) > 0
    top = true[:, 2] > 0
    assert np.mean(est[top & faces, 2] > 0) > 0.99 and np.mean(est[~top & faces, 2] < 0) > 0.99


def test_thinner_plate_still_mostly_right():
    # 0.06 thick (about 2.7 spacings): plain Hoppe weights flip one face (about 50% wrong) here.
    p, true = thin_box(4000, (1.0, 1.0, 0.06))
    wrong, _ = _scores(jaxrbf.estimate_normals(p)[0], true)
    assert wrong < 0.02


def test_two_spheres_are_two_components_each_outward():
    a, ta = sphere(800, centre=(-1.5, 0, 0))
    b, tb = sphere(800, 0.5, centre=(1.5, 0, 0))
    est, rep = jaxrbf.estimate_normals(np.vstack([a, b]), k=10)
    assert rep.components == 2
    assert _scores(est, np.vstack([ta, tb]))[0] == 0.0


def test_duplicates_share_a_normal():
    p, true = sphere(600)
    est, _ = jaxrbf.estimate_normals(np.vstack([p, p[:50]]))
    np.testing.assert_array_equal(est[600:], est[:50])
    assert _scores(est[:600], true)[0] == 0.0


def test_a_plane_is_handled():
    g = np.stack(np.meshgrid(np.arange(10.0), np.arange(10.0)), -1).reshape(-1, 2)
    p = np.column_stack([g, np.zeros(len(g))])
    est, _ = jaxrbf.estimate_normals(p, k=8)
    assert np.all(np.abs(est[:, 2]) > 0.999) and len(np.unique(np.sign(est[:, 2]))) == 1


@pytest.mark.parametrize(
    "points, k, match",
    [
        (np.zeros((5, 3)) + np.arange(5)[:, None], 8, "5 distinct points.*at least 9"),
        (np.vstack([np.ones((20, 3)), np.zeros((3, 3))]), 8, r"2 distinct points \(21 of"),
        (np.array([[0.0, 0, 0], [1, np.nan, 0]] * 20), 8, "NaN or infinite"),
        (np.zeros((20, 2)), 8, r"\(n, 3\) array"),
        (sphere(100)[0], 2, "at least 3 neighbours"),
    ],
)
def test_bad_input_is_an_input_error(points, k, match):
    with pytest.raises(jaxrbf.InputError, match=match):
        jaxrbf.estimate_normals(points, k=k)


def test_fit_surface_estimates_normals_when_asked_or_missing(capsys):
    p, _ = sphere(400)
    model = jaxrbf.fit_surface(p, "auto", offset=0.02, remove_outliers=False)
    err = capsys.readouterr().err
    assert "no normals given, estimating them" in err and "estimated normals of 400" in err
    vals = np.asarray(model(np.array([[0.0, 0, 0], [2.0, 0, 0]])))
    assert vals[0] < 0 < vals[1]  # inside negative, outside positive
    with pytest.raises(jaxrbf.InputError, match="no normals"):
        jaxrbf.constraints_from(p, "given")
    with pytest.raises(jaxrbf.InputError, match="unknown `normals` 'guess'"):
        jaxrbf.constraints_from(p, "guess")


def test_cli_reconstructs_a_bare_point_cloud(tmp_path, capsys):
    p, _ = sphere(500)
    cloud = tmp_path / "cloud.ply"
    jaxrbf.io.write_points(cloud, p)
    assert jaxrbf.io.read_points(cloud).normals is None
    out = tmp_path / "out.ply"
    code = main(["reconstruct", str(cloud), "-o", str(out), "--resolution", "32"])
    err = capsys.readouterr().err
    assert code == 0, err
    assert "estimating them" in err and "output mesh is watertight" in err
    mesh = jaxrbf.io.read_mesh(out)
    r = np.linalg.norm(mesh.vertices, axis=1)
    assert abs(r.mean() - 1) < 0.02 and jaxrbf.is_watertight(mesh)

    code = main(["reconstruct", str(cloud), "-o", str(tmp_path / "no.ply"), "--normals", "given"])
    err = capsys.readouterr().err
    assert code == 2 and "no normals" in err and "--normals estimate" in err
    assert not (tmp_path / "no.ply").exists()


def _graph(p, k=12):
    from scipy.spatial import cKDTree

    _, idx = cKDTree(p).query(p, k=k + 1)
    return np.repeat(np.arange(len(p)), k), idx[:, 1:].reshape(-1)


def test_vote_flips_isolated_wrong_normals_only():
    from jaxrbf._normals import _both_ways, _vote

    p, true = sphere(1500)
    bad = np.random.default_rng(0).choice(len(p), 30, replace=False)
    n = true.copy()
    n[bad] *= -1
    rows, cols = _graph(p)
    rows, cols = _both_ways(rows, cols, np.ones(len(rows), dtype=bool))
    fixed, count = _vote(n, rows, cols)
    assert count == 30 and np.all(np.einsum("ij,ij->i", fixed, true) > 0)
    # Edges marked as crossing to another sheet do not vote: nothing changes without any.
    same, none = _vote(n, *_both_ways(rows, cols, np.zeros(len(rows), dtype=bool)))
    assert none == 0 and np.array_equal(same, n)


def test_doubtful_normals_at_an_edge_are_refilled_from_their_neighbours():
    from jaxrbf._normals import _both_ways, _fill_doubtful

    p, true = thin_box(3000, size=(1.0, 1.0, 1.0))
    n = true.copy()
    # A normal across the surface (along the edge direction) at points near the edge x = y = 0.5.
    near = np.flatnonzero((p[:, 0] > 0.45) & (p[:, 1] > 0.45) & (np.abs(p[:, 2]) < 0.3))[:10]
    n[near] = [0.0, 0.0, 1.0]
    rows, cols = _graph(p)
    out = _fill_doubtful(n, *_both_ways(rows, cols, np.ones(len(rows), dtype=bool)))
    # Now through the surface: out along the true normal, no longer along the edge.
    dots = np.einsum("ij,ij->i", out[near], true[near])  # the planted ones had 0
    assert np.all(dots > 0.2) and dots.mean() > 0.6, dots
    # Normals on the faces, away from every edge, are left alone.
    inside = np.all(np.abs(p) < 0.4, axis=1) | (np.sum(np.abs(p) < 0.4, axis=1) == 2)
    inside[near] = False
    assert inside.sum() > 1000 and np.array_equal(out[inside], n[inside])


def test_noisy_scans_orient_as_well_as_clean_ones():
    # Noise of a point spacing: many nearest neighbours sit along the normal, not beside it.
    p, true = ellipsoid(6000, noise=0.006, seed=4)
    est, rep = jaxrbf.estimate_normals(p)
    wrong, _ = _scores(est, true)
    assert wrong < 0.002, (wrong, rep.summary())


def test_given_normals_that_point_either_way_are_oriented_and_keep_their_directions():
    from jaxrbf._normals import orient_normals

    a, ta = sphere(800, centre=(-1.5, 0, 0))
    b, tb = sphere(800, 0.5, centre=(1.5, 0, 0))
    p, true = np.vstack([a, b]), np.vstack([ta, tb])
    # tilted a little (a given normal is data: its direction is kept), then flipped at random
    rng = np.random.default_rng(3)
    given = true + 0.1 * rng.standard_normal(true.shape)
    given /= np.linalg.norm(given, axis=1, keepdims=True)
    given *= np.where(rng.random(len(p)) < 0.5, -1.0, 1.0)[:, None]
    out = orient_normals(p, given)
    assert _scores(out, true)[0] == 0.0
    np.testing.assert_allclose(np.abs(np.sum(out * given, axis=1)), 1.0)
