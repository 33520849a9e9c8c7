"""File formats: round trips, error messages and atomic writes."""

import os
import zipfile
from pathlib import Path

import numpy as np
import pytest
from helpers import box

from jaxrbf import io
from jaxrbf._errors import InputError

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data"

# A box: 8 vertices, 12 outward triangles (independent of trimesh).
CUBE_V, CUBE_F = box([0.1, -3.0, 1e-3], [1.25, 0.5, 2.0])


def _cloud(n=50, seed=1):
    rng = np.random.default_rng(seed)
    p = rng.normal(size=(n, 3)) * [3.0, 1.0, 1e-2] + 100.0
    nrm = rng.normal(size=(n, 3))
    return p, nrm / np.linalg.norm(nrm, axis=1, keepdims=True)


def _triangles(v, f):
    """Triangles as a sorted list of corner tuples: compares meshes regardless of vertex order."""
    return sorted(tuple(map(tuple, np.round(v[t], 5))) for t in f)


# --------------------------------------------------------------------------- round trips


@pytest.mark.parametrize("ext", [".ply", ".obj", ".off", ".npz"])
def test_mesh_round_trip_exact(tmp_path, ext):
    path = tmp_path / f"cube{ext}"
    io.write_mesh(path, io.Mesh(CUBE_V, CUBE_F))
    m = io.read_mesh(path)
    assert m.vertices.dtype == np.float64 and m.faces.dtype == np.int64
    np.testing.assert_array_equal(m.faces, CUBE_F)
    np.testing.assert_allclose(m.vertices, CUBE_V, rtol=0, atol=1e-14)


def test_mesh_round_trip_stl_joins_corners(tmp_path):
    path = tmp_path / "cube.stl"
    io.write_mesh(path, CUBE_V, CUBE_F)
    m = io.read_mesh(path)
    # STL keeps no shared vertices; reading joins identical corners back into 8 vertices.
    assert m.vertices.shape == (8, 3) and m.faces.shape == (12, 3)
    assert _triangles(m.vertices, m.faces) == _triangles(CUBE_V, CUBE_F)
    assert np.abs(np.sort(m.vertices, axis=0) - np.sort(CUBE_V, axis=0)).max() < 1e-6


def test_write_mesh_accepts_pairs_and_trimesh(tmp_path):
    import trimesh

    io.write_mesh(tmp_path / "a.obj", (CUBE_V, CUBE_F))
    io.write_mesh(tmp_path / "b.obj", trimesh.Trimesh(CUBE_V, CUBE_F, process=False))
    for name in ("a.obj", "b.obj"):
        np.testing.assert_array_equal(io.read_mesh(tmp_path / name).faces, CUBE_F)


def test_ply_mesh_is_readable_by_trimesh(tmp_path):
    import trimesh

    io.write_mesh(tmp_path / "cube.ply", CUBE_V, CUBE_F)
    tm = trimesh.load(str(tmp_path / "cube.ply"), process=False)
    assert tm.is_watertight and tm.volume == pytest.approx(1.25 * 0.5 * 2.0)


@pytest.mark.parametrize("ext", [".ply", ".xyz", ".npz"])
def test_points_with_normals_round_trip(tmp_path, ext):
    p, n = _cloud()
    path = tmp_path / f"cloud{ext}"
    io.write_points(path, p, n)
    pc = io.read_points(path)
    np.testing.assert_array_equal(pc.points, p)
    np.testing.assert_array_equal(pc.normals, n)
    got = io.read_input(path)
    assert isinstance(got, io.PointCloud)
    np.testing.assert_array_equal(got.normals, n)


@pytest.mark.parametrize("ext", [".ply", ".xyz", ".npz"])
def test_points_without_normals(tmp_path, ext):
    p, _ = _cloud()
    io.write_points(tmp_path / f"c{ext}", p)
    pc = io.read_points(tmp_path / f"c{ext}")
    assert pc.normals is None
    np.testing.assert_array_equal(pc.points, p)


def test_ply_normals_written_by_hand_ascii(tmp_path):
    """An ASCII PLY from another tool with float normals: trimesh keeps them only in metadata."""
    path = tmp_path / "hand.ply"
    path.write_text(
        "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\n"
        "property float z\nproperty float nx\nproperty float ny\nproperty float nz\n"
        "property uchar red\nend_header\n0 1 2 0 0 1 255\n3 4 5 1 0 0 0\n"
    )
    pc = io.read_points(path)
    np.testing.assert_array_equal(pc.points, [[0, 1, 2], [3, 4, 5]])
    np.testing.assert_array_equal(pc.normals, [[0, 0, 1], [1, 0, 0]])


def test_txt_points_with_comment(tmp_path):
    path = tmp_path / "p.txt"
    path.write_text("# x y z\n0 0 0\n1 2 3\n")
    pc = io.read_points(path)
    np.testing.assert_array_equal(pc.points, [[0, 0, 0], [1, 2, 3]])
    assert pc.normals is None


def test_2d_points_npz(tmp_path):
    p = np.array([[0.0, 1.0], [2.0, 3.0], [4.0, 5.0]])
    io.write_points(tmp_path / "p.npz", p, -p)
    pc = io.read_points(tmp_path / "p.npz")
    np.testing.assert_array_equal(pc.normals, -p)


def test_read_input_dispatch(tmp_path):
    io.write_mesh(tmp_path / "m.ply", CUBE_V, CUBE_F)
    io.write_mesh(tmp_path / "m.npz", CUBE_V, CUBE_F)
    io.write_points(tmp_path / "p.ply", *_cloud())
    np.save(tmp_path / "l.npy", np.eye(3)[:, :2])
    assert isinstance(io.read_input(tmp_path / "m.ply"), io.Mesh)
    assert isinstance(io.read_input(tmp_path / "m.npz"), io.Mesh)
    assert isinstance(io.read_input(tmp_path / "p.ply"), io.PointCloud)
    assert isinstance(io.read_input(tmp_path / "l.npy"), io.Polyline)


def test_polyline_csv_closed_by_repeat(tmp_path):
    path = tmp_path / "sq.csv"
    path.write_text("x,y\n0,0\n1,0\n1,1\n0,1\n0,0\n")
    pl = io.read_polyline(path)
    assert pl.closed
    np.testing.assert_array_equal(pl.vertices, [[0, 0], [1, 0], [1, 1], [0, 1]])


def test_polyline_csv_open_no_header(tmp_path):
    path = tmp_path / "open.csv"
    path.write_text("0,0\n1,0.5\n2,-1e-3\n")
    pl = io.read_polyline(path)
    assert not pl.closed
    np.testing.assert_array_equal(pl.vertices, [[0, 0], [1, 0.5], [2, -1e-3]])
    assert io.read_polyline(path, closed=True).closed


def test_polyline_npy_open_and_closed(tmp_path):
    t = np.linspace(0, 2 * np.pi, 9)[:-1]
    ring = np.stack([np.cos(t), np.sin(t)], 1)
    np.save(tmp_path / "closed.npy", np.vstack([ring, ring[:1]]))
    np.save(tmp_path / "open.npy", ring)
    closed = io.read_polyline(tmp_path / "closed.npy")
    assert closed.closed and closed.vertices.shape == (8, 2)
    np.testing.assert_array_equal(closed.vertices, ring)
    opened = io.read_polyline(tmp_path / "open.npy")
    assert not opened.closed and opened.vertices.shape == (8, 2)


def test_write_polylines_csv_and_npz(tmp_path):
    a = np.array([[0.0, 0.0], [1.0, 0.0], [0.5, 1.0 / 3.0]])
    b = np.array([[5.0, 5.0], [6.0, 5.0]])
    io.write_polylines(tmp_path / "c.csv", [a, b])
    lines = (tmp_path / "c.csv").read_text().splitlines()
    assert lines[0] == "contour,x,y" and len(lines) == 1 + 5
    table = np.loadtxt(tmp_path / "c.csv", delimiter=",", skiprows=1)
    np.testing.assert_array_equal(table[:, 0], [0, 0, 0, 1, 1])
    np.testing.assert_array_equal(table[:, 1:], np.vstack([a, b]))
    io.write_polylines(tmp_path / "c.npz", [a, b])
    with np.load(tmp_path / "c.npz") as z:
        assert sorted(z.files) == ["contour_0", "contour_1"]
        np.testing.assert_array_equal(z["contour_1"], b)
    # A single-contour file reads back as a polyline.
    io.write_polylines(tmp_path / "one.csv", [a])
    np.testing.assert_array_equal(io.read_polyline(tmp_path / "one.csv").vertices, a)
    with pytest.raises(InputError, match="holds 2 contours"):
        io.read_polyline(tmp_path / "c.csv")


@pytest.mark.skipif(not DATA.exists(), reason="the shared test meshes (../shared/data) are absent")
def test_read_spot():
    m = io.read_mesh(DATA / "spot.obj")
    lines = (DATA / "spot.obj").read_text().splitlines()
    v = np.array([line.split()[1:4] for line in lines if line.startswith("v ")], dtype=float)
    f = np.array(
        [
            [int(w.split("/")[0]) - 1 for w in line.split()[1:]]
            for line in lines
            if line.startswith("f ")
        ]
    )
    # The vertices are the file's `v` lines, in order: no splitting along texture seams.
    np.testing.assert_array_equal(m.vertices, v)
    np.testing.assert_array_equal(m.faces, f)
    assert isinstance(io.read_input(DATA / "spot.obj"), io.Mesh)


# --------------------------------------------------------------------------- errors


def test_missing_file(tmp_path):
    with pytest.raises(InputError, match=r"input file '.*x\.ply' does not exist"):
        io.read_input(tmp_path / "x.ply")
    with pytest.raises(InputError, match="does not exist"):
        io.read_mesh(tmp_path / "x.obj")


@pytest.mark.parametrize("name", ["x.obj", "x.ply", "x.xyz", "x.npz", "x.csv", "x.stl"])
def test_empty_file(tmp_path, name):
    (tmp_path / name).write_bytes(b"")
    with pytest.raises(InputError, match=r"'.*x\.\w+' is empty: it holds no vertices"):
        io.read_input(tmp_path / name)


def test_no_vertices_obj(tmp_path):
    (tmp_path / "x.obj").write_text("# only a comment\n")
    with pytest.raises(InputError, match="is empty: it holds no vertices"):
        io.read_mesh(tmp_path / "x.obj")


def test_unknown_extension(tmp_path):
    (tmp_path / "x.foo").write_text("1 2 3\n")
    with pytest.raises(
        InputError,
        match=r"'.*x\.foo' has an unknown format '\.foo'; expected one "
        r"of \.obj, \.ply",
    ):
        io.read_input(tmp_path / "x.foo")


def test_obj_keeps_unreferenced_vertices_and_splits_quads(tmp_path):
    (tmp_path / "q.obj").write_text(
        "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 9 9 9\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n"
        "f 1/1 2/2 3/3 4/4\n"
    )
    m = io.read_mesh(tmp_path / "q.obj")
    assert m.vertices.shape == (5, 3) and m.vertices[4].tolist() == [9, 9, 9]
    assert m.faces.shape == (2, 3)
    assert {tuple(sorted(t)) for t in m.faces.tolist()} == {(0, 1, 2), (0, 2, 3)}


def test_mesh_without_faces(tmp_path):
    (tmp_path / "x.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\n")
    with pytest.raises(InputError, match=r"'.*x\.obj' has vertices but no faces"):
        io.read_mesh(tmp_path / "x.obj")
    io.write_points(tmp_path / "p.ply", *_cloud())
    with pytest.raises(InputError, match="has vertices but no faces"):
        io.read_mesh(tmp_path / "p.ply")


def test_nan_coordinates(tmp_path):
    (tmp_path / "x.xyz").write_text("0 0 0\nnan 1 1\n1 inf 1\n2 2 -inf\n3 3 3\n")
    with pytest.raises(InputError, match=r"'.*x\.xyz' has 3 vertices with NaN or infinite"):
        io.read_points(tmp_path / "x.xyz")
    (tmp_path / "x.obj").write_text("v nan 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    with pytest.raises(InputError, match="has 1 vertex with NaN or infinite"):
        io.read_mesh(tmp_path / "x.obj")
    np.save(tmp_path / "x.npy", np.array([[0, 0], [1, np.nan], [2, 2]]))
    with pytest.raises(InputError, match="has 1 vertex with NaN"):
        io.read_polyline(tmp_path / "x.npy")


def test_truncated_npz(tmp_path):
    path = tmp_path / "x.npz"
    p, n = _cloud(2000)
    np.savez(path, points=p, normals=n)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(InputError, match=r"'.*x\.npz' could not be read as an \.npz archive"):
        io.read_points(path)
    with pytest.raises(InputError, match="could not be read"):
        io.read_input(path)


def test_corrupt_npz_member(tmp_path):
    """A zip whose member is not a valid .npy."""
    path = tmp_path / "x.npz"
    with zipfile.ZipFile(path, "w") as z:
        z.writestr("points.npy", b"not an npy file")
    with pytest.raises(InputError, match="could not be read as an .npz archive"):
        io.read_points(path)


def test_truncated_ply(tmp_path):
    path = tmp_path / "x.ply"
    io.write_points(path, *_cloud(100))
    data = path.read_bytes()
    path.write_bytes(data[: len(data) - 500])
    with pytest.raises(InputError, match=r"'.*x\.ply' could not be read as PLY"):
        io.read_points(path)
    ascii_ply = tmp_path / "a.ply"
    ascii_ply.write_text(
        "ply\nformat ascii 1.0\nelement vertex 3\nproperty double x\nproperty double y\n"
        "property double z\nend_header\n0.1 0.2 0.3\n"
    )
    with pytest.raises(InputError, match="declares 3 vertices, which need .* truncated"):
        io.read_points(ascii_ply)


def test_wrong_columns(tmp_path):
    # 4 columns (x y z intensity) are now read (test_xyz_extra_columns); 1 or 2 are refused.
    (tmp_path / "x.xyz").write_text("0 0\n1 1\n")
    with pytest.raises(InputError, match=r"has 2 columns; a point list needs at least 3 \(x y z"):
        io.read_points(tmp_path / "x.xyz")
    (tmp_path / "one.txt").write_text("0\n1\n")
    with pytest.raises(InputError, match=r"'.*one\.txt' has 1 column; a point list needs"):
        io.read_input(tmp_path / "one.txt")
    (tmp_path / "x.csv").write_text("x,y,z\n0,0,0\n1,1,1\n")
    with pytest.raises(
        InputError,
        match="has 3 columns; a polyline needs exactly 2 .* use read_points or read_input",
    ):
        io.read_polyline(tmp_path / "x.csv")
    np.save(tmp_path / "x.npy", np.zeros((4, 3)))
    with pytest.raises(InputError, match=r"shape \(4, 3\); expected \(n, 2\)"):
        io.read_polyline(tmp_path / "x.npy")
    (tmp_path / "ragged.xyz").write_text("0 0 0\n1 1\n")
    with pytest.raises(InputError, match="could not be read as a point list"):
        io.read_points(tmp_path / "ragged.xyz")


def test_wrong_npz_keys(tmp_path):
    np.savez(tmp_path / "x.npz", pts=np.zeros((3, 3)))
    with pytest.raises(
        InputError, match=r"has arrays \['pts'\]; a point-cloud .npz needs `points`"
    ):
        io.read_points(tmp_path / "x.npz")
    with pytest.raises(InputError, match=r"has arrays \['pts'\]; expected `points`"):
        io.read_input(tmp_path / "x.npz")
    np.savez(tmp_path / "y.npz", points=np.zeros((3, 3)), normals=np.zeros((2, 3)))
    with pytest.raises(InputError, match="`normals` must have the shape of `points`"):
        io.read_points(tmp_path / "y.npz")


def test_bad_face_index(tmp_path):
    (tmp_path / "x.off").write_text("OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n")
    with pytest.raises(InputError, match=r"could not be read as OFF: .*face index"):
        io.read_mesh(tmp_path / "x.off")
    np.savez(tmp_path / "x.npz", vertices=CUBE_V, faces=np.vstack([CUBE_F, [[0, 1, 8]]]))
    with pytest.raises(InputError, match=r"has 1 face referring to vertices it does not hold"):
        io.read_input(tmp_path / "x.npz")
    (tmp_path / "x.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 2 4\nf 0 1 2\n")
    with pytest.raises(InputError, match=r"could not be read as OBJ: line 6"):
        io.read_mesh(tmp_path / "x.obj")


def test_corrupt_off(tmp_path):
    (tmp_path / "x.off").write_text("OFF\n3 1 0\n0 0 0\n")
    with pytest.raises(InputError, match=r"'.*x\.off' could not be read as OFF"):
        io.read_mesh(tmp_path / "x.off")


def test_wrong_kind_for_reader(tmp_path):
    io.write_points(tmp_path / "p.xyz", *_cloud())
    with pytest.raises(InputError, match=r"holds a point cloud \(\.xyz\)"):
        io.read_mesh(tmp_path / "p.xyz")


def test_short_polyline(tmp_path):
    (tmp_path / "x.csv").write_text("0,0\n1,1\n0,0\n")
    with pytest.raises(InputError, match="closed polyline needs at least 3"):
        io.read_polyline(tmp_path / "x.csv")


# --------------------------------------------------------------------------- as_points


def test_as_points_valid():
    a = io.as_points([[1, 2, 3], [4, 5, 6]])
    assert a.dtype == np.float64 and a.shape == (2, 3)


@pytest.mark.parametrize(
    "array, dims, pattern",
    [
        (
            np.zeros(3),
            (2, 3),
            r"`points` must be a 2-dimensional array of shape \(n, d\), got "
            r"shape \(3,\)",
        ),
        (np.zeros((4, 4)), (2, 3), r"must have 2 or 3 columns"),
        (np.zeros((4, 2)), (3,), r"must have 3 columns"),
        (np.zeros((0, 3)), (2, 3), "is empty"),
        (np.array([[0, 0], [np.nan, 1], [np.inf, 0]]), (2,), "has 2 rows with NaN or infinite"),
        ([["a", "b"]], (2,), "must be an array of numbers"),
    ],
)
def test_as_points_errors(array, dims, pattern):
    with pytest.raises(InputError, match=pattern):
        io.as_points(array, dims=dims)


def test_as_points_names_the_argument():
    with pytest.raises(InputError, match="`centres` must be a 2-dimensional"):
        io.as_points(np.zeros((2, 2, 2)), "centres")


# --------------------------------------------------------------------------- atomic writes


def _listing(folder):
    return sorted(os.listdir(folder))


@pytest.mark.parametrize(
    "writer, args",
    [
        (io.write_mesh, (CUBE_V, CUBE_F)),
        (io.write_points, (CUBE_V,)),
        (io.write_polylines, ([CUBE_V[:, :2]],)),
    ],
)
def test_unknown_output_extension_writes_nothing(tmp_path, writer, args):
    with pytest.raises(InputError, match="supported output formats"):
        writer(tmp_path / "out.foo", *args)
    assert _listing(tmp_path) == []


def test_bad_array_writes_nothing(tmp_path):
    with pytest.raises(InputError, match="refers to vertex indices from 1 to 8"):
        io.write_mesh(tmp_path / "m.obj", CUBE_V, CUBE_F + 1)
    with pytest.raises(InputError, match="has 1 row with NaN"):
        io.write_points(tmp_path / "p.xyz", [[0, 0, np.nan]])
    assert _listing(tmp_path) == []


def test_missing_output_folder(tmp_path):
    with pytest.raises(InputError, match="does not exist; create it first"):
        io.write_mesh(tmp_path / "nope" / "m.obj", CUBE_V, CUBE_F)


def test_failed_write_keeps_old_file(tmp_path, monkeypatch):
    target = tmp_path / "m.obj"
    target.write_text("old content\n")

    def broken(tmp, v, f, ext):
        with open(tmp, "w") as fh:
            fh.write("v 0 0 0\n")  # some bytes, then a failure
        raise RuntimeError("disk full")

    monkeypatch.setattr(io, "_write_text_mesh", broken)
    with pytest.raises(RuntimeError, match="disk full"):
        io.write_mesh(target, CUBE_V, CUBE_F)
    assert target.read_text() == "old content\n"
    assert _listing(tmp_path) == ["m.obj"]


def test_failed_trimesh_export_keeps_old_file(tmp_path, monkeypatch):
    import trimesh

    target = tmp_path / "m.stl"
    target.write_bytes(b"old")

    def broken(self, file_obj=None, file_type=None, **kw):
        with open(file_obj, "wb") as fh:
            fh.write(b"solid partial\n")
        raise OSError("exporter crashed")

    monkeypatch.setattr(trimesh.Trimesh, "export", broken)
    with pytest.raises(OSError, match="exporter crashed"):
        io.write_mesh(target, CUBE_V, CUBE_F)
    assert target.read_bytes() == b"old"
    assert _listing(tmp_path) == ["m.stl"]


def test_atomic_output_replaces_on_success(tmp_path):
    target = tmp_path / "t.txt"
    target.write_text("old")
    with io.atomic_output(target) as tmp:
        assert Path(tmp).parent == tmp_path and Path(tmp).suffix == ".txt"
        assert target.read_text() == "old"  # not yet replaced
        Path(tmp).write_text("new")
    assert target.read_text() == "new"
    assert _listing(tmp_path) == ["t.txt"]


def test_atomic_output_normal_permissions(tmp_path):
    io.write_points(tmp_path / "p.xyz", CUBE_V)
    umask = os.umask(0)
    os.umask(umask)
    assert (tmp_path / "p.xyz").stat().st_mode & 0o777 == 0o666 & ~umask


# --------------------------------------------------------------------------- scanner text formats


def _sphere_cloud(n=40, seed=3):
    """Points on a sphere with their outward normals (components of every sign), colours 0-255
    and intensities: the columns scanners and CloudCompare write."""
    rng = np.random.default_rng(seed)
    nrm = rng.normal(size=(n, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    rgb = rng.integers(0, 256, size=(n, 3)).astype(float)
    rgb[0] = 0  # a black point: a row of zeros in colour columns
    intensity = rng.uniform(0, 4000, size=(n, 1))
    return 2.0 * nrm + [5.0, -1.0, 0.5], nrm, rgb, intensity


@pytest.mark.parametrize(
    "layout, has_normals",
    [
        ("p n", True),
        ("p rgb", False),
        ("p rgb01", False),
        ("p i", False),
        ("p rgb n", True),
        ("p n rgb", True),
        ("p i rgb", False),
        ("p i n", True),
        ("p i rgb n", True),
        ("p n i", True),
    ],
)
def test_xyz_extra_columns(tmp_path, layout, has_normals):
    p, n, rgb, i = _sphere_cloud()
    columns = {"p": p, "n": n, "rgb": rgb, "rgb01": rgb / 255, "i": i}
    path = tmp_path / "scan.xyz"
    np.savetxt(path, np.hstack([columns[c] for c in layout.split()]), fmt="%.17g")
    for cloud in (io.read_points(path), io.read_input(path)):
        np.testing.assert_array_equal(cloud.points, p)
        if has_normals:
            np.testing.assert_array_equal(cloud.normals, n)
        else:
            assert cloud.normals is None


def test_xyz_normals_facing_one_side_zero_rows_and_named_columns(tmp_path):
    p, n, rgb, _ = _sphere_cloud()
    up = n * np.sign(n[:, 2:])  # a terrain's normals: nz never negative, unit length
    np.savetxt(tmp_path / "up.xyz", np.hstack([p, rgb, up]))
    np.testing.assert_allclose(io.read_points(tmp_path / "up.xyz").normals, up, atol=1e-15)
    # Signed columns with a row of zeros are normals with one missing, not dropped unsaid: they
    # are passed on, to be refused as a zero-length normal.
    bad = n.copy()
    bad[7] = 0
    np.savetxt(tmp_path / "zero.xyz", np.hstack([p, bad]))
    np.testing.assert_allclose(io.read_points(tmp_path / "zero.xyz").normals, bad, atol=1e-15)
    # ... unless another triple qualifies.
    np.savetxt(tmp_path / "later.xyz", np.hstack([p, bad, n]))
    np.testing.assert_allclose(io.read_points(tmp_path / "later.xyz").normals, n, atol=1e-15)
    # A signed scalar beside the normals (a signed distance, say): the triple of unit rows wins
    # over one that straddles the scalar and two normal components.
    s = np.random.default_rng(4).normal(size=(len(p), 1))
    np.savetxt(tmp_path / "sn.xyz", np.hstack([p, s, n]))
    np.testing.assert_allclose(io.read_points(tmp_path / "sn.xyz").normals, n, atol=1e-15)
    np.savetxt(tmp_path / "zs.xyz", np.hstack([p, bad, s]))
    np.testing.assert_allclose(io.read_points(tmp_path / "zs.xyz").normals, bad, atol=1e-15)
    # A header naming the normals settles it, whatever their signs.
    flat = np.tile([0.0, 0.0, 1.0], (len(p), 1))
    body = "\n".join(" ".join(f"{v:.17g}" for v in row) for row in np.hstack([p, rgb, flat]))
    (tmp_path / "named.txt").write_text("//X Y Z R G B Nx Ny Nz\n" + body + "\n")
    np.testing.assert_array_equal(io.read_points(tmp_path / "named.txt").normals, flat)


@pytest.mark.parametrize(
    "name, text",
    [
        ("comma.xyz", "x,y,z,nx,ny,nz\n0,1,2,0,0,-1\n3,4,5,0,-1,0\n6,7,8,-1,0,0\n"),
        (
            "spaced.csv",
            "# scan\nX, Y, Z, NX, NY, NZ\n0, 1, 2, 0, 0, -1\n3, 4, 5, 0, -1, 0\n"
            "6, 7, 8, -1, 0, 0\n",
        ),
        ("semi.txt", "0;1;2;0;0;-1\n3;4;5;0;-1;0 # a comment\n6; 7; 8;-1;0;0\n"),
        ("cc.txt", "//X Y Z Nx Ny Nz\n0 1 2 0 0 -1\n\n3 4 5 0 -1 0\n6 7 8 -1 0 0\n"),
    ],
    ids=["comma", "spaced-csv", "semicolon", "cloudcompare"],
)
def test_point_list_separators_and_header(tmp_path, name, text):
    (tmp_path / name).write_text(text)
    for cloud in (io.read_points(tmp_path / name), io.read_input(tmp_path / name)):
        assert isinstance(cloud, io.PointCloud)
        np.testing.assert_array_equal(cloud.points, [[0, 1, 2], [3, 4, 5], [6, 7, 8]])
        np.testing.assert_array_equal(cloud.normals, [[0, 0, -1], [0, -1, 0], [-1, 0, 0]])


def test_point_list_header_errors(tmp_path):
    # Only one header line, and only one without numbers: a broken first row is not skipped.
    (tmp_path / "two.xyz").write_text("x y z\nx y z\n1 2 3\n")
    with pytest.raises(InputError, match=r"'.*two\.xyz' .* line 2: 'x' is not a number"):
        io.read_points(tmp_path / "two.xyz")
    (tmp_path / "row.xyz").write_text("1 2 abc\n1 2 3\n")
    with pytest.raises(InputError, match=r"'.*row\.xyz' .* line 1: 'abc' is not a number"):
        io.read_points(tmp_path / "row.xyz")
    (tmp_path / "ragged.csv").write_text("x,y,z\n0,0,0\n1,1\n")
    with pytest.raises(InputError, match=r"line 3 holds 2 numbers but the first data line holds 3"):
        io.read_input(tmp_path / "ragged.csv")
    (tmp_path / "header.txt").write_text("x,y,z\n")
    with pytest.raises(InputError, match=r"'.*header\.txt' is empty: it holds no vertices"):
        io.read_points(tmp_path / "header.txt")
    (tmp_path / "nan.csv").write_text("x,y,z,r,g,b\n0,0,0,1,2,3\nnan,1,1,1,2,3\n")
    with pytest.raises(InputError, match=r"'.*nan\.csv' has 1 vertex with NaN or infinite"):
        io.read_input(tmp_path / "nan.csv")
    (tmp_path / "nrm.xyz").write_text("0 0 0 0 0 -1 5\n1 1 1 -1 0 nan 5\n")
    with pytest.raises(InputError, match=r"'.*nrm\.xyz' has 1 normal with NaN or infinite"):
        io.read_points(tmp_path / "nrm.xyz")
    # A header that puts x y z elsewhere than first: refused, not misread.
    (tmp_path / "f.csv").write_text("polyline,x,y,z\n0,0,0,0\n0,1,0,0\n0,1,1,0\n")
    with pytest.raises(InputError, match=r"names its columns 'polyline x y z'.* start with"):
        io.read_input(tmp_path / "f.csv")


def test_pts(tmp_path):
    path = tmp_path / "scan.pts"
    # x y z intensity r g b; Leica intensities are signed (-2048..2047): still no normals.
    path.write_text("3\n0 1 2 -1200 10 20 30\n3 4 5 -80 0 0 0\n6 7 8 1500 255 255 255\n")
    for cloud in (io.read_points(path), io.read_input(path)):
        np.testing.assert_array_equal(cloud.points, [[0, 1, 2], [3, 4, 5], [6, 7, 8]])
        assert cloud.normals is None
    (tmp_path / "i.pts").write_text("2\n0 1 2 7\n3 4 5 9\n")
    np.testing.assert_array_equal(io.read_input(tmp_path / "i.pts").points, [[0, 1, 2], [3, 4, 5]])
    (tmp_path / "short.pts").write_text("4\n0 1 2\n3 4 5\n6 7 8\n")
    with pytest.raises(InputError, match=r"'.*short\.pts' declares 4 points on line 1, but 3 rows"):
        io.read_input(tmp_path / "short.pts")
    (tmp_path / "long.pts").write_text("1\n0 1 2\n3 4 5\n")
    with pytest.raises(InputError, match=r"declares 1 point on line 1, but 2 rows"):
        io.read_points(tmp_path / "long.pts")
    (tmp_path / "x.pts").write_bytes(b"")
    with pytest.raises(InputError, match=r"'.*x\.pts' is empty"):
        io.read_input(tmp_path / "x.pts")
    assert io.SUPPORTED[".pts"] == "point cloud"
    with pytest.raises(InputError, match=r"holds a point cloud \(\.pts\)"):
        io.read_mesh(path)
    (tmp_path / "m.stl").write_text("solid x\n")
    with pytest.raises(InputError, match=r"expected one of .*\.pts"):
        io.read_points(tmp_path / "m.stl")
    (tmp_path / "m.foo").write_text("1 2 3\n")
    with pytest.raises(InputError, match=r"expected one of .*\.pts"):
        io.read_input(tmp_path / "m.foo")


def test_csv_point_cloud_or_polyline(tmp_path):
    p, n, rgb, _ = _sphere_cloud()
    rows = np.hstack([p, rgb, n])
    body = "\n".join(",".join(f"{v:.17g}" for v in row) for row in rows)
    (tmp_path / "cloud.csv").write_text("x,y,z,r,g,b,nx,ny,nz\n" + body + "\n")
    for cloud in (io.read_input(tmp_path / "cloud.csv"), io.read_points(tmp_path / "cloud.csv")):
        assert isinstance(cloud, io.PointCloud)
        np.testing.assert_array_equal(cloud.points, p)
        np.testing.assert_array_equal(cloud.normals, n)
    (tmp_path / "bare.csv").write_text("1,2,3\n4,5,6\n7,8,9\n")
    assert io.read_input(tmp_path / "bare.csv").normals is None
    # Two columns stay a polyline, and so does a write_polylines file (contour,x,y).
    (tmp_path / "line.csv").write_text("x,y\n0,0\n1,0\n1,1\n")
    assert isinstance(io.read_input(tmp_path / "line.csv"), io.Polyline)
    with pytest.raises(InputError, match=r"has 2 columns; .* a 2-column \.csv is a 2-D polyline"):
        io.read_points(tmp_path / "line.csv")
    io.write_polylines(tmp_path / "c.csv", [np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])])
    assert isinstance(io.read_input(tmp_path / "c.csv"), io.Polyline)
    with pytest.raises(InputError, match=r"'contour x y'.* 2-D curve file: read it with"):
        io.read_points(tmp_path / "c.csv")


def test_obj_without_faces_is_a_point_cloud(tmp_path):
    v = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\n"
    vn = "vn -1 -1 -1\nvn 1 0 0\nvn 0 1 0\nvn 0 0 1\n"
    (tmp_path / "n.obj").write_text("# scan\n" + v + vn)
    cloud = io.read_input(tmp_path / "n.obj")
    assert isinstance(cloud, io.PointCloud)
    np.testing.assert_array_equal(cloud.points, np.vstack([np.zeros(3), np.eye(3)]))
    np.testing.assert_array_equal(cloud.normals, [[-1, -1, -1], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    (tmp_path / "few.obj").write_text(v + "vn 0 0 1\n")
    cloud = io.read_input(tmp_path / "few.obj")
    assert isinstance(cloud, io.PointCloud) and cloud.normals is None
    (tmp_path / "bare.obj").write_text(v)
    assert io.read_input(tmp_path / "bare.obj").normals is None
    with pytest.raises(InputError, match=r"'.*bare\.obj' has vertices but no faces"):
        io.read_mesh(tmp_path / "bare.obj")
    (tmp_path / "badvn.obj").write_text(v + "vn 0 0 1\nvn 0 0\nvn 0 0 1\nvn 0 0 1\n")
    with pytest.raises(InputError, match=r"'.*badvn\.obj' could not be read as OBJ: line 6"):
        io.read_input(tmp_path / "badvn.obj")
    (tmp_path / "nan.obj").write_text(v + vn.replace("vn 1 0 0", "vn nan 0 0"))
    with pytest.raises(InputError, match="has 1 normal with NaN or infinite"):
        io.read_input(tmp_path / "nan.obj")
    # With faces it is a mesh, as before, and a broken `vn` line does not matter there.
    (tmp_path / "m.obj").write_text(v + "vn x\nf 1 2 3\n")
    assert isinstance(io.read_input(tmp_path / "m.obj"), io.Mesh)
