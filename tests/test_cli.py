import json
import subprocess
import sys

import numpy as np
import pytest
from conftest import data_file
from helpers import ellipse, sphere

import jaxrbf
from jaxrbf.cli import main


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.mark.slow
def test_reconstruct_fit_mesh_evaluate_on_spot(tmp_path, capsys):
    spot = data_file("spot.obj")
    out = tmp_path / "spot.ply"
    code, _, err = run(capsys, "reconstruct", spot, "-o", out, "--points", 800, "--resolution", 48)
    assert code == 0, err
    assert "relative residual" in err and "wrote" in err
    code, text, _ = run(capsys, "evaluate", out, "--reference", spot, "--json", "--samples", 20000)
    scores = json.loads(text)
    assert scores["chamfer_l1"] < 0.01 and scores["normal_consistency"] > 0.9

    model = tmp_path / "spot.npz"
    assert run(capsys, "fit", spot, "-o", model, "--points", 300, "-q")[0] == 0
    again = tmp_path / "again.obj"
    code, _, err = run(capsys, "mesh", model, "-o", again, "--resolution", 32, "--project")
    assert code == 0, err
    mesh = jaxrbf.io.read_mesh(again)
    assert (
        np.abs(np.asarray(jaxrbf.load(model)(mesh.vertices))).max() < 1e-6
    )  # projected onto f = 0


def test_fit_then_mesh_is_reconstruct(tmp_path, capsys):
    """A model saved by `fit` carries its samples: `mesh` with no options gives reconstruct's
    mesh (its grid from the samples' spacing, its output check), not a bare 128 grid."""
    p, n = sphere(300)
    src = tmp_path / "ball.ply"
    jaxrbf.io.write_points(src, p, n)
    direct, model, later = tmp_path / "direct.ply", tmp_path / "m.npz", tmp_path / "later.ply"
    code, _, err = run(capsys, "reconstruct", src, "-o", direct)
    assert code == 0, err
    assert run(capsys, "fit", src, "-o", model, "-q")[0] == 0
    code, _, err = run(capsys, "mesh", model, "-o", later)
    assert code == 0, err
    assert "from the samples' point spacing" in err and "output accounts for its input" in err
    a, b = jaxrbf.io.read_mesh(direct), jaxrbf.io.read_mesh(later)
    np.testing.assert_array_equal(a.faces, b.faces)
    np.testing.assert_allclose(a.vertices, b.vertices, rtol=0, atol=1e-9)
    _, samples, normals = jaxrbf.load_fit(model)
    assert samples.shape == (300, 3) and normals.shape == (300, 3)


@pytest.mark.slow
def test_open_pieces_are_thickened_by_default_or_closed_on_request(tmp_path, capsys):
    """A bent open sheet: by default a thin slab round it (and `fit` + `mesh` give the same);
    `--open-pieces close` closes it instead, with surface far off the sheet."""
    rng = np.random.default_rng(0)
    xy = rng.uniform(-1, 1, (600, 2))
    p = np.column_stack([xy, 0.3 * xy[:, 0] ** 2])
    n = np.column_stack([-0.6 * xy[:, 0], np.zeros(600), np.ones(600)])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    src = tmp_path / "sheet.ply"
    jaxrbf.io.write_points(src, p, n)

    def off_sheet(path):
        v = jaxrbf.io.read_mesh(path).vertices
        return np.abs(v[:, 2] - 0.3 * v[:, 0] ** 2).max()

    thin, closed = tmp_path / "thin.ply", tmp_path / "closed.ply"
    code, _, err = run(capsys, "reconstruct", src, "-o", thin)
    assert code == 0, err
    assert "600 samples on 1 open piece" in err and "1 thin slab" in err
    assert off_sheet(thin) < 0.02  # a spacing is about 0.08
    model, later = tmp_path / "m.npz", tmp_path / "later.ply"
    assert run(capsys, "fit", src, "-o", model, "-q")[0] == 0
    fitted = jaxrbf.load_fit(model)
    assert len(fitted[1]) == 0 and len(fitted.shells[0]) == 600
    code, _, err = run(capsys, "mesh", model, "-o", later)
    assert code == 0, err
    np.testing.assert_allclose(
        jaxrbf.io.read_mesh(later).vertices, jaxrbf.io.read_mesh(thin).vertices
    )
    code, _, err = run(capsys, "reconstruct", src, "-o", closed, "--open-pieces", "close")
    assert code == 0, err
    assert "open piece" not in err and off_sheet(closed) > 0.1


def test_point_cloud_and_kernel_options(tmp_path, capsys):
    p, n = sphere(300)
    src = tmp_path / "ball.xyz"
    np.savetxt(src, np.hstack([p, n]))
    out = tmp_path / "ball.stl"
    code, _, err = run(
        capsys,
        "reconstruct",
        src,
        "-o",
        out,
        "--kernel",
        "multiquadric",
        "--radius",
        0.1,
        "--solver",
        "cholesky",
        "--resolution",
        32,
        "-q",
    )
    assert code == 0, err
    v = jaxrbf.io.read_mesh(out).vertices
    assert np.abs(np.linalg.norm(v, axis=1) - 1).max() < 0.01
    # a Gaussian as wide as the shape makes the system numerically singular: a clear error
    code, _, err = run(
        capsys,
        "reconstruct",
        src,
        "-o",
        tmp_path / "g.ply",
        "--kernel",
        "gaussian",
        "--radius",
        0.3,
        "--solver",
        "cholesky",
        "-q",
    )
    assert code == 2 and "singular" in err and not (tmp_path / "g.ply").exists()


def test_polyline_to_curves(tmp_path, capsys):
    src = tmp_path / "ellipse.csv"
    np.savetxt(src, ellipse(40, closed_repeat=True), delimiter=",")
    out = tmp_path / "curve.csv"
    code, _, err = run(capsys, "reconstruct", src, "-o", out, "--resolution", 100)
    assert code == 0, err
    rows = np.loadtxt(out, delimiter=",", skiprows=1)
    assert np.abs((rows[:, 1] / 2) ** 2 + rows[:, 2] ** 2 - 1).max() < 0.03


def _bad_inputs(tmp_path):
    """(name, file content writer, expected message) for each kind of bad input."""
    p, n = sphere(50)
    cases = {}
    (tmp_path / "empty.obj").write_text("")
    cases["empty"] = (tmp_path / "empty.obj", "empty")
    bad = np.hstack([p, n])
    bad[3, 0] = np.nan
    np.savetxt(tmp_path / "nan.xyz", bad)
    cases["nan"] = (tmp_path / "nan.xyz", "NaN")
    (tmp_path / "scan.foo").write_text("1 2 3\n")
    cases["unknown"] = (tmp_path / "scan.foo", "unknown format '.foo'")
    # (an .obj of vertices alone is a point cloud; an .off says it is a mesh)
    (tmp_path / "nofaces.off").write_text("OFF\n4 0 0\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n")
    cases["no faces"] = (tmp_path / "nofaces.off", "no faces")
    zero = np.hstack([p, n])
    zero[7, 3:] = 0
    np.savetxt(tmp_path / "zero.xyz", zero)
    cases["zero normals"] = (tmp_path / "zero.xyz", "zero-length")
    flat = np.hstack([p[:, :2], np.zeros((50, 1)), np.tile([0, 0, 1.0], (50, 1))])
    np.savetxt(tmp_path / "flat.xyz", flat)
    cases["plane"] = (tmp_path / "flat.xyz", "lie on one plane")
    # (a point repeated with its own normal is merged: a mesh's vertices exported per face)
    np.savetxt(tmp_path / "twin.xyz", np.tile(np.hstack([p[:1], n[:1]]), (60, 1)))
    cases["identical points"] = (tmp_path / "twin.xyz", "on one plane")
    return cases


@pytest.mark.parametrize(
    "case", ["empty", "nan", "unknown", "no faces", "zero normals", "plane", "identical points"]
)
def test_bad_input_gives_one_line_error_and_no_output(case, tmp_path, capsys):
    path, message = _bad_inputs(tmp_path)[case]
    out = tmp_path / "out.ply"
    code, _, err = run(capsys, "reconstruct", path, "-o", out)
    assert code == 2
    assert message in err and err.startswith("jaxrbf: error:")
    assert "Traceback" not in err
    assert not out.exists()


def test_bad_model_files_given_to_mesh(tmp_path, capsys):
    p, n = sphere(60)
    good = tmp_path / "good.npz"
    jaxrbf.save(jaxrbf.fit(jaxrbf.Constraints.from_points(p, n)), good)
    cut = tmp_path / "cut.npz"
    cut.write_bytes(good.read_bytes()[:300])
    foreign = tmp_path / "foreign.npz"
    np.savez(foreign, points=p)
    out = tmp_path / "out.ply"
    for path, message in [
        (cut, "truncated or corrupt"),
        (foreign, "not a jaxrbf model"),
        (tmp_path / "missing.npz", "does not exist"),
    ]:
        code, _, err = run(capsys, "mesh", path, "-o", out)
        assert code == 2 and message in err and "Traceback" not in err
        assert not out.exists()


def test_existing_output_survives_a_failure(tmp_path, capsys):
    out = tmp_path / "keep.ply"
    out.write_bytes(b"precious")
    (tmp_path / "empty.obj").write_text("")
    assert run(capsys, "reconstruct", tmp_path / "empty.obj", "-o", out)[0] == 2
    assert out.read_bytes() == b"precious"


def test_bad_output_is_refused_before_any_work(tmp_path, capsys):
    p, n = sphere(50)
    np.savetxt(tmp_path / "ball.xyz", np.hstack([p, n]))
    code, _, err = run(capsys, "reconstruct", tmp_path / "ball.xyz", "-o", tmp_path / "out.docx")
    assert code == 2 and "unsupported format '.docx'" in err and "solving" not in err
    code, _, err = run(
        capsys, "reconstruct", tmp_path / "ball.xyz", "-o", tmp_path / "nope" / "o.ply"
    )
    assert code == 2 and "does not exist" in err
    code, _, err = run(capsys, "reconstruct", "-o", tmp_path / "o.ply")
    assert code == 2 and "no input" in err


def test_console_script_entry_point(tmp_path):
    """The installed command, in a separate process: exit status and a clean one-line error."""
    (tmp_path / "empty.ply").write_text("")
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "jaxrbf.cli",
            "reconstruct",
            str(tmp_path / "empty.ply"),
            "-o",
            str(tmp_path / "o.ply"),
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 2
    assert proc.stderr.strip().count("\n") == 0 and "jaxrbf: error:" in proc.stderr
    assert not (tmp_path / "o.ply").exists()


@pytest.mark.slow
def test_method_option_partition_fit_mesh(tmp_path, capsys, monkeypatch):
    """`--method partition` through the CLI: the model is saved, reloaded and meshed."""
    from jaxrbf import _partition

    monkeypatch.setattr(_partition, "BASE_SIZE", 300)
    p, n = sphere(700)
    cloud = tmp_path / "ball.xyz"
    np.savetxt(cloud, np.hstack([p, n]))
    model = tmp_path / "ball.npz"
    code, _, err = run(capsys, "fit", cloud, "-o", model, "--method", "partition")
    assert code == 0, err
    assert "patches on 2 levels" in err and "relative residual" in err
    assert isinstance(jaxrbf.load(model), jaxrbf.PartitionModel)
    out = tmp_path / "ball.ply"
    code, _, err = run(capsys, "mesh", model, "-o", out, "--resolution", 40)
    assert code == 0, err
    v = jaxrbf.io.read_mesh(out).vertices
    assert np.abs(np.linalg.norm(v, axis=1) - 1).max() < 0.02
    with pytest.raises(SystemExit):
        run(capsys, "fit", cloud, "-o", model, "--method", "fast")
    assert "invalid choice: 'fast'" in capsys.readouterr().err


def test_progress_bars_follow_one_convention(capsys):
    """Bars go to stderr: shown when asked (True), hidden when told (False), and by default
    only on a terminal (pytest's captured stderr is not one)."""
    from jaxrbf._constraints import progress_bar

    with progress_bar(3, "quiet by default", "step", None) as bar:
        assert bar.disable
    with progress_bar(3, "hidden", "step", False) as bar:
        assert bar.disable
    with progress_bar(3, "asked for", "step", True) as bar:
        bar.update(3)
    captured = capsys.readouterr()
    assert "asked for" in captured.err and "hidden" not in captured.err
    assert captured.out == ""


def _soup(mesh, turn):
    """`mesh` as a polygon soup (each face its own three vertices), the faces `turn` wound the
    other way."""
    v = np.asarray(mesh.vertices)[np.asarray(mesh.faces)].reshape(-1, 3)
    f = np.arange(len(v)).reshape(-1, 3)
    f[turn] = f[turn][:, ::-1]
    return v, f


def test_consistent_winding_turns_faces_against_their_neighbours():
    import trimesh

    from jaxrbf._prepare import consistent_winding

    rng = np.random.default_rng(0)
    ball = trimesh.creation.icosphere(3)  # outward
    box = trimesh.creation.box([0.5, 0.5, 0.5])
    box.apply_translation([3.0, 0.0, 0.0])
    m1, m2 = len(ball.faces), len(box.faces)
    # the ball: 40% of its faces turned; the box: wound inside out, 3 of its 12 faces turned back
    v1, f1 = _soup(ball, rng.random(m1) < 0.4)
    turn = np.ones(m2, dtype=bool)
    turn[:3] = False
    v2, f2 = _soup(box, turn)
    v, f = np.vstack([v1, v2]), np.vstack([f1, f2 + len(v1)])
    out, turned = consistent_winding(v, f)
    normal = np.cross(v[out[:, 1]] - v[out[:, 0]], v[out[:, 2]] - v[out[:, 0]])
    centre = np.where(np.arange(len(f))[:, None] < m1, 0.0, [3.0, 0.0, 0.0])
    outward = np.sum(normal * (v[out].mean(axis=1) - centre), axis=1) > 0
    # each piece takes the winding of most of its area: the ball outward, the box inward
    assert outward[:m1].all() and not outward[m1:].any()
    assert turned == int(np.sum(f1 != out[:m1]) / 2) + 3
    same, none = consistent_winding(ball.vertices, ball.faces)
    assert none == 0 and np.array_equal(same, ball.faces)


def test_a_soup_wound_at_random_is_reconstructed(tmp_path, capsys):
    """A sphere as a polygon soup with a third of its faces wound the other way: the command
    line turns them (and says so) and meshes the sphere."""
    import trimesh

    rng = np.random.default_rng(1)
    ball = trimesh.creation.icosphere(3)
    v, f = _soup(ball, rng.random(len(ball.faces)) < 0.33)
    src, out = tmp_path / "soup.obj", tmp_path / "out.ply"
    jaxrbf.io.write_mesh(src, jaxrbf.io.Mesh(v, f))
    code, _, err = run(capsys, "reconstruct", src, "-o", out, "--points", 1500, "--resolution", 48)
    assert code == 0, err
    assert "faces were wound against their neighbours" in err
    assert "input mesh has 0 boundary loops" in err  # a soup is no mesh of 1,280 holes
    r = np.linalg.norm(jaxrbf.io.read_mesh(out).vertices, axis=1)
    assert np.abs(r - 1).max() < 0.03, np.abs(r - 1).max()


def test_repeated_points_with_their_own_normals_are_merged_not_refused(tmp_path, capsys):
    """A mesh's vertices exported with normals repeat a vertex once per face along its creases
    and seams: such a cloud gives a surface (before: 'their normals disagree', exit 2)."""
    from jaxrbf._reconstruct import fit_surface_samples

    p, n = sphere(1500)
    rng = np.random.default_rng(2)
    crease = rng.choice(1500, 100, replace=False)
    tilt = np.cross(n[crease], rng.standard_normal((100, 3)))
    tilt /= np.linalg.norm(tilt, axis=1, keepdims=True)
    copy = np.cos(1.2) * n[crease] + np.sin(1.2) * tilt  # 69 degrees off: cosine 0.36
    edge = np.setdiff1d(np.arange(1500), crease)[:10]  # copies facing the other way
    pts = np.vstack([p, p[crease], p[edge]])
    nrm = np.vstack([n, copy, -n[edge]])
    src, out = tmp_path / "verts.ply", tmp_path / "out.ply"
    jaxrbf.io.write_points(src, pts, nrm)
    code, _, err = run(capsys, "reconstruct", src, "-o", out, "--resolution", 48)
    assert code == 0, err
    assert "120 repeated points" in err and "100 merged" in err and "20 dropped" in err
    r = np.linalg.norm(jaxrbf.io.read_mesh(out).vertices, axis=1)
    assert np.abs(r - 1).max() < 0.02
    _, samples, normals = fit_surface_samples(pts, nrm)
    assert len(samples) == 1490
    merged = np.isin(samples, p[crease]).all(axis=1)
    assert merged.sum() == 100
    # a crease's vertex gets the mean of its faces' normals
    mean = n[crease] + copy
    mean /= np.linalg.norm(mean, axis=1, keepdims=True)
    order = [int(np.flatnonzero((p[crease] == s).all(axis=1))[0]) for s in samples[merged]]
    np.testing.assert_allclose(normals[merged], mean[order], atol=1e-12)


def test_strays_in_a_clean_cloud_with_normals_are_removed(tmp_path, capsys):
    """A clean cloud with normals and 2% stray points in its box (random normals): before, each
    stray grew a blob of its own and the command wrote them all (exit 0)."""
    from jaxrbf._clean import isolated

    p, n = sphere(2000)
    rng = np.random.default_rng(8)
    strays = rng.uniform(-1.6, 1.6, (40, 3))
    strays = strays[np.abs(np.linalg.norm(strays, axis=1) - 1) > 0.3]  # not on the sphere
    sn = rng.standard_normal(strays.shape)
    pts, nrm = np.vstack([p, strays]), np.vstack([n, sn])
    found = isolated(pts)
    assert found[2000:].mean() > 0.6 and not found[:2000].any()
    # density changing tenfold over the surface is no stray
    many, _ = sphere(20000)
    dense = np.vstack([p[p[:, 0] > 0], many[many[:, 0] <= 0]])
    assert not isolated(dense).any()
    src, out = tmp_path / "strays.ply", tmp_path / "out.ply"
    jaxrbf.io.write_points(src, pts, nrm)
    code, _, err = run(capsys, "reconstruct", src, "-o", out, "--resolution", 64)
    assert code == 0, err
    assert "stray points" in err
    r = np.linalg.norm(jaxrbf.io.read_mesh(out).vertices, axis=1)
    assert np.abs(r - 1).max() < 0.05, np.abs(r - 1).max()
