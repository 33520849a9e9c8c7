"""Sharp features from the Hessian: a cube's edges, a sphere's curvature, bad input, fandisk."""

import numpy as np
import pytest
from conftest import data_file
from helpers import sphere
from scipy.spatial import cKDTree

import jaxrbf
from jaxrbf import InputError
from jaxrbf.features import (
    FEATURE_FLOOR,
    principal_curvatures,
    sharp_features,
    write_feature_points,
    write_feature_polylines,
)


def _cube_samples(per_face: int, seed: int = 0):
    """Uniform samples on the faces of the unit cube [-0.5, 0.5]^3, with outward normals."""
    rng = np.random.default_rng(seed)
    pts, nrm = [], []
    for axis in range(3):
        for side in (-0.5, 0.5):
            p = np.zeros((per_face, 3))
            others = [i for i in range(3) if i != axis]
            p[:, others] = rng.uniform(-0.5, 0.5, (per_face, 2))
            p[:, axis] = side
            n = np.zeros((per_face, 3))
            n[:, axis] = np.sign(side)
            pts.append(p)
            nrm.append(n)
    return np.vstack(pts), np.vstack(nrm)


def _edge_distance(p):
    """Distance of each point to the nearest of the cube's 12 edges, and which edge (axis, s1, s2)."""
    best = np.full(len(p), np.inf)
    which = np.zeros(len(p), dtype=int)
    k = 0
    for axis in range(3):
        a, b = (i for i in range(3) if i != axis)
        for s1 in (-0.5, 0.5):
            for s2 in (-0.5, 0.5):
                d = np.hypot(p[:, a] - s1, p[:, b] - s2)
                closer = d < best
                best[closer], which[closer] = d[closer], k
                k += 1
    return best, which


@pytest.fixture(scope="module")
def cube_model():
    p, n = _cube_samples(200)
    return jaxrbf.fit(jaxrbf.Constraints.from_points(p, n), method="dense")


@pytest.fixture(scope="module")
def cube_features(cube_model):
    return sharp_features(cube_model, resolution=40, polylines=True)


def test_cube_edges_found(cube_features):
    f = cube_features
    assert len(f) > 100
    dist, which = _edge_distance(f.points)
    # the fit rounds each edge over about a sample spacing (~0.03): points lie in that band
    assert np.mean(dist < 0.1) > 0.95, np.quantile(dist, [0.5, 0.9, 1])
    counts = np.bincount(which[dist < 0.1], minlength=12)
    assert counts.min() >= 5, counts
    # nothing near the face centres
    q = np.abs(f.points)
    near_centre = np.sum(np.sort(q, axis=1)[:, :2] < 0.25, axis=1) == 2
    assert not near_centre.any(), f.points[near_centre]
    assert f.threshold >= FEATURE_FLOOR
    assert np.all(f.sharpness > f.threshold)
    assert f.curvature.shape == (len(f), 2) and f.direction.shape == (len(f), 3)


def test_cube_crease_direction_runs_along_edges(cube_features):
    f = cube_features
    dist, which = _edge_distance(f.points)
    axis = which // 4  # edges 0-3 run along x, 4-7 along y, 8-11 along z
    along = np.abs(f.direction[np.arange(len(f)), axis])
    # away from the corners, the crease direction is the edge's axis
    mid = (dist < 0.1) & (np.abs(f.points[np.arange(len(f)), axis]) < 0.35)
    assert mid.sum() > 50
    assert np.median(along[mid]) > 0.95
    assert np.mean(along[mid] > 0.9) > 0.8


def test_cube_face_centre_flat_edge_curved(cube_model):
    centres = np.array([[0, 0, 0.5], [0, -0.5, 0], [0.5, 0, 0.0]])
    k, _ = principal_curvatures(cube_model, centres)
    assert np.all(np.abs(k) < 0.5), k
    assert principal_curvatures(cube_model, np.zeros((0, 3)))[0].shape == (0, 2)
    mid = sharp_features(cube_model, np.array([[0.5, 0.5, 0.0], [0.5, 0.0, 0.0]]), threshold=20)
    assert len(mid) == 1 and np.abs(mid.points[0] - [0.5, 0.5, 0]).max() < 0.05
    assert mid.curvature[0, 0] > 20  # convex edge: positive curvature with f growing outwards


def test_cube_polylines_follow_edges(cube_features, tmp_path):
    lines = cube_features.polylines
    assert 12 <= len(lines) <= 40, len(lines)
    chained = np.vstack(lines)
    dist, which = _edge_distance(chained)
    assert np.median(dist) < 0.04 and np.mean(dist < 0.1) > 0.95
    # every edge is traced, away from the corners too
    axis = which // 4
    mid = np.abs(chained[np.arange(len(chained)), axis]) < 0.3
    assert np.bincount(which[mid & (dist < 0.1)], minlength=12).min() >= 3
    write_feature_polylines(tmp_path / "c.csv", lines)
    rows = np.loadtxt(tmp_path / "c.csv", delimiter=",", skiprows=1)
    assert rows.shape == (sum(map(len, lines)), 4)
    assert int(rows[:, 0].max()) == len(lines) - 1
    np.testing.assert_array_equal(rows[rows[:, 0] == 0, 1:], lines[0])
    write_feature_polylines(tmp_path / "c.npz", lines)
    with np.load(tmp_path / "c.npz") as z:
        np.testing.assert_array_equal(z[f"polyline_{len(lines) - 1}"], lines[-1])
    write_feature_points(tmp_path / "p.ply", cube_features)
    back = jaxrbf.io.read_points(tmp_path / "p.ply")
    np.testing.assert_allclose(back.points, cube_features.points)
    with pytest.raises(InputError, match="supported: .csv, .npz"):
        write_feature_polylines(tmp_path / "c.txt", lines)
    assert not (tmp_path / "c.txt").exists()


@pytest.fixture(scope="module")
def sphere_model():
    p, n = sphere(400, radius=2.0)
    return jaxrbf.fit(jaxrbf.Constraints.from_points(p, n), method="dense")


def test_sphere_curvature_is_one_over_radius(sphere_model):
    rng = np.random.default_rng(1)
    d = rng.normal(size=(300, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    k, dirs = principal_curvatures(sphere_model, 2.0 * d)
    np.testing.assert_allclose(k, 0.5, rtol=0.05)
    assert abs(np.median(k) - 0.5) < 0.005
    # principal directions: unit, tangent
    np.testing.assert_allclose(np.linalg.norm(dirs, axis=2), 1.0, atol=1e-9)
    assert np.abs(np.einsum("nki,ni->nk", dirs, d)).max() < 0.05
    # an exact sphere (any traceable callable): k = 1/R to round-off, for f growing outwards
    exact, _ = principal_curvatures(lambda x: np.sqrt(3.0) * (jnp_norm(x) - 2.0), 2.0 * d)
    np.testing.assert_allclose(exact, 0.5, rtol=1e-9)
    inside_out, _ = principal_curvatures(lambda x: 2.0 - jnp_norm(x), 2.0 * d)
    np.testing.assert_allclose(inside_out, -0.5, rtol=1e-9)


def jnp_norm(x):
    import jax.numpy as jnp

    return jnp.sqrt(jnp.sum(x * x, axis=-1))


def test_sphere_has_no_sharp_features(sphere_model):
    f = sharp_features(sphere_model, resolution=32)
    assert f.candidates > 1000
    assert len(f) <= 0.01 * f.candidates, (len(f), f.threshold)
    assert f.threshold == FEATURE_FLOOR


def test_bad_input():
    m2 = jaxrbf.fit(
        jaxrbf.Constraints.from_polyline(
            np.stack([np.cos(t := np.linspace(0, 6, 30)), np.sin(t)], 1)
        )
    )
    with pytest.raises(InputError, match="3-D implicit, got a 2-D model"):
        sharp_features(m2)
    ball = jaxrbf.csg.Sphere(radius=1.0)
    pts = np.array([[1.0, 0, 0], [np.nan, 0, 0], [0, 1.0, 0]])
    with pytest.raises(InputError, match="`points` has 1 rows with NaN"):
        sharp_features(ball, pts)
    with pytest.raises(InputError, match="`points` has 1 rows with NaN"):
        principal_curvatures(ball, pts)
    with pytest.raises(InputError, match=r"`points` must have shape \(n, 3\), got \(4,\)"):
        sharp_features(ball, np.zeros(4))
    with pytest.raises(InputError, match="`threshold` must be a positive number"):
        sharp_features(ball, np.eye(3), threshold=-1.0)
    with pytest.raises(InputError, match="`implicit` must be a callable"):
        sharp_features("model.npz", np.eye(3))


def _crease_edges(v, f, degrees: float = 30.0):
    fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    fn /= np.linalg.norm(fn, axis=1, keepdims=True)
    e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    face = np.tile(np.arange(len(f)), 3)
    key = e[:, 0] * len(v) + e[:, 1]
    order = np.argsort(key, kind="stable")
    key, e, face = key[order], e[order], face[order]
    i = np.flatnonzero(key[1:] == key[:-1])
    cos = np.sum(fn[face[i]] * fn[face[i + 1]], axis=1)
    return e[i[cos < np.cos(np.radians(degrees))]]


@pytest.mark.slow
def test_fandisk_creases_found():
    mesh = jaxrbf.io.read_mesh(data_file("fandisk.obj"))
    v, f = mesh.vertices, mesh.faces
    diag = float(np.linalg.norm(np.ptp(v, axis=0)))
    model = jaxrbf.fit(jaxrbf.Constraints.from_mesh(v, f, points=1500), method="dense")
    feats = sharp_features(model, resolution=64)
    creases = _crease_edges(v, f)
    assert len(creases) > 500
    t = np.linspace(0.0, 1.0, 11)[:, None, None]
    samples = ((1 - t) * v[creases[:, 0]] + t * v[creases[:, 1]]).reshape(-1, 3)
    d, _ = cKDTree(samples).query(feats.points)
    precision = np.mean(d < 0.02 * diag)  # measured 0.97
    back, _ = cKDTree(feats.points).query(v[creases].mean(axis=1))
    recall = np.mean(back < 0.02 * diag)  # measured 0.93
    assert precision > 0.9 and recall > 0.85, (precision, recall)


def test_cli_pieces(cube_model, tmp_path):
    import argparse

    from jaxrbf.features import add_features_parser, run_features

    parser = argparse.ArgumentParser(prog="jaxrbf")
    add_features_parser(parser.add_subparsers(dest="command"))
    saved = tmp_path / "cube.npz"
    jaxrbf.save(cube_model, saved)
    out, lines = tmp_path / "creases.ply", tmp_path / "creases.csv"
    args = parser.parse_args(
        [
            "features",
            str(saved),
            "-o",
            str(out),
            "--resolution",
            "32",
            "--polylines",
            str(lines),
            "-q",
        ]
    )
    assert run_features(args) == 0
    pts = jaxrbf.io.read_points(out).points
    assert len(pts) > 50 and np.mean(_edge_distance(pts)[0] < 0.1) > 0.95
    rows = np.loadtxt(lines, delimiter=",", skiprows=1)
    assert rows.shape[1] == 4 and len(rows) > 20
    bad = parser.parse_args(["features", str(saved), "-o", str(tmp_path / "c.obj")])
    with pytest.raises(InputError, match="cannot write feature points to .*c.obj"):
        run_features(bad)
    none = parser.parse_args(
        ["features", str(saved), "-o", str(out), "--threshold", "1e9", "--resolution", "24"]
    )
    out.unlink()
    with pytest.raises(InputError, match=r"no sharp features: .* lower --threshold"):
        run_features(none)
    assert not out.exists()


def test_features_command(cube_model, tmp_path):
    # `jaxrbf features MODEL.npz -o creases.ply` through the real command line
    from jaxrbf.cli import main

    model_path = tmp_path / "cube.npz"
    jaxrbf.save(cube_model, model_path)
    out = tmp_path / "creases.ply"
    assert main(["features", str(model_path), "-o", str(out), "--resolution", "40", "-q"]) == 0
    pts = jaxrbf.io.read_input(out).points
    assert len(pts) > 50
    assert np.median(_edge_distance(pts)) < 0.1
    assert main(["features", str(model_path), "-o", str(tmp_path / "x.stl"), "-q"]) == 2
