"""Outlier removal, boundary loops and watertightness."""

import numpy as np
import pytest
from helpers import sphere

import jaxrbf
from jaxrbf.cli import main


def icosphere(subdivisions=3):
    import trimesh

    m = trimesh.creation.icosphere(subdivisions=subdivisions)
    return jaxrbf.io.Mesh(np.asarray(m.vertices), np.asarray(m.faces))


def with_hole(mesh, z=0.8):
    """`mesh` without the faces whose centroid lies above `z` (one round hole)."""
    keep = mesh.vertices[mesh.faces].mean(axis=1)[:, 2] < z
    return jaxrbf.io.Mesh(mesh.vertices, mesh.faces[keep])


def test_outliers_added_to_a_sphere_are_removed():
    p, n = sphere(3000)
    rng = np.random.default_rng(1)
    far = rng.uniform(-2.0, 2.0, (60, 3))
    far = far[np.abs(np.linalg.norm(far, axis=1) - 1) > 0.3]  # clearly off the surface
    pts = np.vstack([p, far])
    nrm = np.vstack([n, np.tile([0.0, 0, 1], (len(far), 1))])
    kept_p, kept_n, rep = jaxrbf.remove_outliers(pts, nrm)
    assert rep.n == len(pts) and rep.dropped == len(pts) - len(kept_p)
    assert kept_n.shape == kept_p.shape
    outlier_kept = np.sum(np.abs(np.linalg.norm(kept_p, axis=1) - 1) > 0.3)
    assert outlier_kept <= 0.1 * len(far)  # most caught
    inliers_lost = len(p) - np.sum(np.abs(np.linalg.norm(kept_p, axis=1) - 1) < 1e-9)
    assert inliers_lost <= 0.01 * len(p)  # few inliers lost
    assert "removed" in rep.summary()
    # Without normals, and nothing to remove on a clean sphere.
    q, qn, rep = jaxrbf.remove_outliers(p, std_ratio=5.0)
    assert qn is None and rep.dropped == 0 and len(q) == len(p)


@pytest.mark.parametrize(
    "kw, match",
    [
        (dict(k=0), "at least 1 neighbour"),
        (dict(std_ratio=-1.0), "positive number"),
        (dict(k=5000), "needs at least 5001"),
        (dict(normals=np.zeros((3, 3))), "shape of `points`"),
    ],
)
def test_remove_outliers_bad_input(kw, match):
    with pytest.raises(jaxrbf.InputError, match=match):
        jaxrbf.remove_outliers(sphere(100)[0], **kw)


def test_boundary_loops_and_watertight():
    m = icosphere(2)
    assert jaxrbf.boundary_loops(m) == 0 and jaxrbf.is_watertight(m)
    holed = with_hole(m)
    assert jaxrbf.boundary_loops(holed) == 1 and not jaxrbf.is_watertight(holed)
    two = with_hole(jaxrbf.io.Mesh(holed.vertices * [1, 1, -1], holed.faces), z=0.8)
    assert jaxrbf.boundary_loops(two) == 2  # holes at both poles
    flipped = m.faces.copy()
    flipped[0] = flipped[0, ::-1]  # one face the wrong way round
    assert not jaxrbf.is_watertight(jaxrbf.io.Mesh(m.vertices, flipped))
    assert jaxrbf.boundary_loops(np.zeros((0, 3), int)) == 0
    with pytest.raises(jaxrbf.InputError, match=r"\(m, 3\) faces"):
        jaxrbf.is_watertight(np.zeros((4, 4), int))


def test_sphere_with_a_hole_reconstructs_watertight(tmp_path, capsys):
    holed = with_hole(icosphere(3))
    path = tmp_path / "holed.obj"
    jaxrbf.io.write_mesh(path, holed)
    assert jaxrbf.boundary_loops(jaxrbf.io.read_mesh(path)) == 1
    out = tmp_path / "closed.ply"
    code = main(["reconstruct", str(path), "-o", str(out), "--points", "600", "--resolution", "32"])
    err = capsys.readouterr().err
    assert code == 0, err
    assert "input mesh has 1 boundary loop" in err and "output mesh is watertight" in err
    mesh = jaxrbf.io.read_mesh(out)
    assert jaxrbf.is_watertight(mesh) and jaxrbf.boundary_loops(mesh) == 0


def test_reconstruct_removes_outliers_of_a_cloud(capsys):
    p, n = sphere(600)
    far = np.array([[1.8, 0, 0], [0, -1.7, 0.2], [0.1, 0.2, 1.9]])
    pts = np.vstack([p, far])
    nrm = np.vstack([n, far / np.linalg.norm(far, axis=1, keepdims=True)])
    c = jaxrbf.constraints_from(pts, nrm, remove_outliers=True, verbose=True)
    assert "removed 3 outliers of 603" in capsys.readouterr().err
    assert c.n_surface == 600


def test_strays_a_few_spacings_off_the_surface_are_removed():
    p, n = sphere(3000)
    dirs = np.random.default_rng(5).normal(size=(8, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    strays = dirs * 1.18  # ~3 spacings off the sphere (spacing 0.062)
    far = np.random.default_rng(6).uniform(-2, 2, (30, 3))  # 1% far away: they set the std
    far = far[np.linalg.norm(far, axis=1) > 1.5]
    pts = np.vstack([p, strays, far])
    kept_first, _, rep_first = jaxrbf.remove_outliers(pts, plane_ratio=None)
    assert rep_first.off_plane == 0 and rep_first.plane_ratio is None
    assert np.sum(np.linalg.norm(kept_first, axis=1) > 1.1) >= 4  # strays it keeps
    kept, _, rep = jaxrbf.remove_outliers(pts)
    r = np.linalg.norm(kept, axis=1)
    assert np.all(r < 1.1)  # every stray gone
    assert len(kept) >= 3000 - 3  # and hardly any surface point
    assert rep.off_plane > 0 and "from its plane" in rep.summary()
    with pytest.raises(jaxrbf.InputError, match="plane_ratio"):
        jaxrbf.remove_outliers(pts, plane_ratio=-1.0)


def test_a_sparse_stretch_of_surface_is_not_taken_for_outliers():
    # a real scan's density varies several-fold (distance to the scanner, oblique views): the
    # global test alone drops whole sparse stretches; strays in the volume still go
    rng = np.random.default_rng(2)
    dense = np.c_[rng.uniform(0, 1, (20000, 2)), 0.001 * rng.standard_normal(20000)]
    sparse = np.c_[rng.uniform(1, 1.5, (800, 1)), rng.uniform(0, 1, (800, 1)), np.zeros(800)]
    strays = rng.uniform([0, 0, 0.2], [1.5, 1, 1.0], (20, 3))
    pts = np.vstack([dense, sparse, strays])
    kept, _, rep = jaxrbf.remove_outliers(pts)
    old, _, _ = jaxrbf.remove_outliers(pts, flat_ratio=None)
    on_sparse = lambda q: np.sum((q[:, 0] > 1) & (np.abs(q[:, 2]) < 0.01))  # noqa: E731
    assert on_sparse(old) < 0.85 * len(sparse)  # the density-biased test alone loses them
    assert on_sparse(kept) >= 0.98 * len(sparse)
    assert np.sum(kept[:, 2] > 0.1) == 0  # strays still dropped
