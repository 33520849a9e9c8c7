"""Hostile and broken inputs, generated here (no binary fixtures): every one is refused early,
with exit status 2 and one line that names the real problem, nothing written and nothing
clobbered; a legitimate awkward input (triangle strips, a very long output name) gives a sound
result.

Most cases run the command in-process (`jaxrbf.cli.main`); a few run the installed script, where
its exit status and stderr are what matter. No case fits a surface: each refusal comes before
any fit, which is what the cases check."""

import os
import subprocess
import sys
import tempfile
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest
from helpers import ellipse, sphere

import jaxrbf
from jaxrbf import _util, io
from jaxrbf._errors import InputError
from jaxrbf._prepare import sample_faces
from jaxrbf.cli import main
from jaxrbf.kernels import KERNELS

#: A refusal of a hostile size must come within this many seconds.
QUICK = 10.0
#: Words that must never reach the user: internal exception names, unsafe-loading advice.
FORBIDDEN = (
    "Traceback",
    "ValueError",
    "TypeError",
    "InputError",
    "KeyError",
    "IndexError",
    "MemoryError",
    "OSError",
    "pickle",
    "allow_pickle",
)
PRECIOUS = b"precious: must survive every refusal"


# --------------------------------------------------------------------------- generators


def npy_bytes(shape, descr="<f8", body=b"\0" * 64) -> bytes:
    """A .npy file whose header claims `shape`, followed by only `body`."""
    header = f"{{'descr': '{descr}', 'fortran_order': False, 'shape': {tuple(shape)!r}, }}"
    header += " " * (117 - len(header)) + "\n"
    return b"\x93NUMPY\x01\x00" + len(header).to_bytes(2, "little") + header.encode() + body


def ply_header(fmt, elements) -> bytes:
    """A PLY header; `elements` is a list of (name, count, [property lines])."""
    lines = ["ply", f"format {fmt} 1.0"]
    for name, count, props in elements:
        lines.append(f"element {name} {count}")
        lines += [f"property {p}" for p in props]
    return ("\n".join(lines + ["end_header"]) + "\n").encode()


XYZ = ["float x", "float y", "float z"]
FACE = ["list uchar int vertex_indices"]


def ascii_ply(vertices, faces, declared_faces=None) -> bytes:
    nf = len(faces) if declared_faces is None else declared_faces
    head = ply_header("ascii", [("vertex", len(vertices), XYZ), ("face", nf, FACE)])
    body = [" ".join(map(str, v)) for v in vertices]
    body += [f"{len(f)} " + " ".join(map(str, f)) for f in faces]
    return head + ("\n".join(body) + "\n").encode()


def icosahedron():
    import trimesh

    m = trimesh.creation.icosphere(1)
    return np.asarray(m.vertices), np.asarray(m.faces)


def rbf_model(dim=3):
    """A small `RBFModel` built directly (no fit): cubic kernel, centres on a sphere/circle."""
    import jax.numpy as jnp

    p = sphere(20)[0] if dim == 3 else ellipse(16, 1.0, 1.0)
    return jaxrbf.RBFModel(
        centres=jnp.asarray(0.4 * p),
        weights=jnp.full(len(p), 1.0 / len(p)),
        coeffs=jnp.asarray([-0.1]),
        kernel=KERNELS["cubic"](),
        shift=jnp.zeros(dim),
        scale=jnp.asarray(1.0),
        residual=jnp.asarray(0.0),
        degree=0,
        background=None,
    )


@pytest.fixture(scope="module")
def model_fields(tmp_path_factory):
    """The fields of a valid saved 3-D model."""
    path = tmp_path_factory.mktemp("model") / "good.npz"
    jaxrbf.save(rbf_model(), path)
    with np.load(path) as z:
        return dict(z)


@pytest.fixture(scope="module")
def model_files(tmp_path_factory):
    folder = tmp_path_factory.mktemp("models")
    jaxrbf.save(rbf_model(3), folder / "m3.npz")
    jaxrbf.save(rbf_model(2), folder / "m2.npz")
    return folder


def cli(capsys, *argv):
    """Run the command in-process: (exit status, stderr, seconds)."""
    t0 = time.perf_counter()
    try:
        code = main([str(a) for a in argv])
    except SystemExit as e:  # argparse
        code = e.code
    seconds = time.perf_counter() - t0
    _, err = capsys.readouterr()
    return code, err, seconds


def assert_refused(code, err, *words, seconds=None):
    """Exit 2, one line `jaxrbf: error: ...` holding every one of `words`, nothing forbidden."""
    assert code == 2, err
    lines = [line for line in err.strip().splitlines() if line.strip()]
    errors = [line for line in lines if line.startswith("jaxrbf: error:")]
    assert len(errors) == 1, err
    assert "jaxrbf: error: jaxrbf" not in err and "error: error" not in err
    for word in words:
        assert word in errors[0], (word, errors[0])
    for word in FORBIDDEN:
        assert word not in err, (word, err)
    if seconds is not None:
        assert seconds < QUICK, f"refused after {seconds:.1f} s"


def refuse(capsys, tmp_path, command, source, *options, words=(), ext=None, quick=False):
    """`jaxrbf command source -o tmp/out.EXT options` over a pre-existing output: refused with
    `words`, the output untouched and no file left behind in its folder. `ext` default: `.csv`
    for a polyline input, else `.ply`."""
    if ext is None:
        ext = ".csv" if str(source).endswith((".csv", ".npy")) else ".ply"
    out_dir = Path(tempfile.mkdtemp(dir=tmp_path))
    out = out_dir / f"result{ext}"
    out.write_bytes(PRECIOUS)
    code, err, seconds = cli(capsys, command, source, "-o", out, "-q", *options)
    assert_refused(code, err, *words, seconds=seconds if quick else None)
    assert out.read_bytes() == PRECIOUS
    assert sorted(os.listdir(out_dir)) == [out.name]
    return err


# --------------------------------------------------------------------------- 1. sizes on trust


HUGE = 10**12


@pytest.mark.parametrize(
    "name, content, words",
    [
        ("huge.npy", npy_bytes((HUGE, 2)), ["huge.npy", "shape (1000000000000, 2)", "truncated"]),
        (
            "huge.npz",
            {"points.npy": npy_bytes((HUGE, 3))},
            ["huge.npz", "array 'points'", "(1000000000000, 3)", "truncated"],
        ),
        (
            "huge_mesh.npz",
            {"vertices.npy": npy_bytes((4, 3), body=b"\0" * 96), "faces.npy": npy_bytes((HUGE, 3))},
            ["array 'faces'", "truncated"],
        ),
        (
            "vertices.ply",
            ply_header("binary_little_endian", [("vertex", HUGE, XYZ)]) + b"\0" * 120,
            ["vertices.ply", "1,000,000,000,000 vertices", "only 120", "truncated"],
        ),
        (
            "faces.ply",
            ply_header("ascii", [("vertex", 3, XYZ), ("face", 10**9, FACE)])
            + b"0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n",
            ["faces.ply", "1,000,000,000 faces", "truncated"],
        ),
        (
            "huge.off",
            b"OFF\n1000000000000 1000000000000 0\n0 0 0\n",
            ["huge.off", "1,000,000,000,000 vertices", "line 2", "truncated"],
        ),
        (
            "huge.stl",
            b"\0" * 80 + (10**9).to_bytes(4, "little") + b"\0" * 100,
            ["huge.stl", "1,000,000,000 triangles", "truncated"],
        ),
    ],
)
def test_header_sizes_checked_against_the_bytes(tmp_path, capsys, name, content, words):
    path = tmp_path / name
    if isinstance(content, dict):
        with zipfile.ZipFile(path, "w") as z:
            for member, data in content.items():
                z.writestr(member, data)
    else:
        path.write_bytes(content)
    with pytest.raises(InputError) as e:
        io.read_input(path)
    for word in words:
        assert word in str(e.value)
    refuse(capsys, tmp_path, "reconstruct", path, words=words, quick=True)


def test_compressed_member_claiming_more_than_it_holds(tmp_path):
    """A deflated member whose .npy header claims far more than the member holds."""
    path = tmp_path / "bomb.npz"
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("points.npy", npy_bytes((10**8, 3), body=b"\0" * 10**6))
    with pytest.raises(InputError, match=r"array 'points' declares .* truncated or corrupt"):
        io.read_points(path)


def test_header_sizes_checked_against_the_memory_bound(tmp_path, monkeypatch):
    """A complete, honest file that needs more memory than is available is refused unread."""
    path = tmp_path / "cloud.npz"
    np.savez(path, points=np.zeros((100_000, 3)))
    monkeypatch.setattr(_util, "available_memory", lambda: 2**20)
    with pytest.raises(InputError, match=r"needs about .* MiB of memory but 1\.0 MiB"):
        io.read_points(path)
    np.save(tmp_path / "curve.npy", np.zeros((100_000, 2)))
    with pytest.raises(InputError, match="of memory but"):
        io.read_polyline(tmp_path / "curve.npy")


def test_huge_model_member(tmp_path, capsys, model_fields):
    path = tmp_path / "m.npz"
    with zipfile.ZipFile(path, "w") as z:
        for k, v in model_fields.items():
            if k != "weights":
                z.writestr(k + ".npy", npy_bytes(v.shape, v.dtype.str, v.tobytes()))
        z.writestr("weights.npy", npy_bytes((HUGE,)))
    with pytest.raises(InputError, match=r"array 'weights' declares .* truncated"):
        jaxrbf.load(path)
    refuse(capsys, tmp_path, "mesh", path, words=["array 'weights'", "truncated"], quick=True)


def test_points_option_checked_before_sampling(tmp_path, capsys):
    v, f = icosahedron()
    mesh = tmp_path / "ico.ply"
    io.write_mesh(mesh, v, f)
    refuse(
        capsys,
        tmp_path,
        "reconstruct",
        mesh,
        "--points",
        "2000000000",
        words=["--points 2,000,000,000", "too many", "GiB"],
        quick=True,
    )
    refuse(capsys, tmp_path, "reconstruct", mesh, "--points", "0", words=["--points", "at least 1"])
    with pytest.raises(InputError, match=r"sampling 2,000,000,000 points .* of memory"):
        sample_faces(v, f, 2_000_000_000)


def test_resolution_checked_before_the_fit(tmp_path, capsys, model_files):
    p, n = sphere(100)
    cloud = tmp_path / "ball.xyz"
    np.savetxt(cloud, np.hstack([p, n]))
    for source, command, ext in (
        (cloud, "reconstruct", ".ply"),
        (model_files / "m3.npz", "mesh", ".ply"),
        (model_files / "m2.npz", "mesh", ".csv"),
    ):
        err = refuse(
            capsys,
            tmp_path,
            command,
            source,
            "--resolution",
            "1000000",
            words=["--resolution 1000000", "of memory", "lower --resolution"],
            ext=ext,
            quick=True,
        )
        assert "solving" not in err
    refuse(
        capsys,
        tmp_path,
        "features",
        model_files / "m3.npz",
        "--resolution",
        "100000",
        words=["--resolution 100000"],
        quick=True,
    )


@pytest.mark.parametrize("value", ["0", "-5", "1"])
@pytest.mark.parametrize("dim, ext", [(2, ".csv"), (3, ".ply")])
def test_tiny_resolution_refused_in_2d_and_3d(tmp_path, capsys, model_files, value, dim, ext):
    refuse(
        capsys,
        tmp_path,
        "mesh",
        model_files / f"m{dim}.npz",
        "--resolution",
        value,
        words=["--resolution must be at least 4", f"got {value}"],
        ext=ext,
    )


def test_grid_sizes_refused_by_the_api(model_files):
    m3, m2 = (jaxrbf.load(model_files / f"m{d}.npz") for d in (3, 2))
    t0 = time.perf_counter()
    with pytest.raises(InputError, match=r"`resolution` 100000 \(a narrow-band .* TiB"):
        jaxrbf.polygonize(m3, 100_000)
    with pytest.raises(InputError, match=r"`resolution` 1000000 .* of memory"):
        jaxrbf.contour(m2, 1_000_000)
    with pytest.raises(InputError, match="at least 2 samples"):
        jaxrbf.contour(m2, 0)
    assert time.perf_counter() - t0 < QUICK


def test_render_size_and_fov(tmp_path, capsys, model_files):
    model = model_files / "m3.npz"
    refuse(
        capsys,
        tmp_path,
        "render",
        model,
        "--size",
        "100000",
        "100000",
        words=["--size 100000 100000", "of memory"],
        ext=".png",
        quick=True,
    )
    refuse(capsys, tmp_path, "render", model, "--size", "0", "9", words=["--size"], ext=".png")
    for fov in ("0", "180", "-10", "nan"):
        refuse(capsys, tmp_path, "render", model, "--fov", fov, words=["--fov", "180"], ext=".png")
    with pytest.raises(InputError, match=r"camera `fov` must be in \(0, 180\)"):
        jaxrbf.Camera.orbit(jaxrbf.load(model), fov=180)


# --------------------------------------------------------------------------- 2. model files


def _model_cases():
    def put(**changes):
        return lambda d: {**d, **changes}

    def drop(key):
        return lambda d: {k: v for k, v in d.items() if k != key}

    def weights(fn):
        return lambda d: {**d, "weights": fn(d["weights"])}

    damaged = "is a damaged jaxrbf model"
    return [
        ("format_version text", put(format_version=np.array("2")), [damaged, "format_version"]),
        (
            "format array",
            put(format=np.array(["jaxrbf-model", "x"])),
            [damaged, "`format`", "shape (2,)"],
        ),
        ("complex weights", weights(lambda w: w.astype(complex)), [damaged, "weights", "complex"]),
        ("text weights", weights(lambda w: w.astype(str)), [damaged, "weights", "real numbers"]),
        ("text radius", put(radius=np.array("abc")), [damaged, "`radius`"]),
        ("text scale", put(scale=np.array("1")), [damaged, "`scale`"]),
        ("NaN centres", lambda d: {**d, "centres": d["centres"] * np.nan}, [damaged, "NaN"]),
        ("negative scale", put(scale=np.array(-1.0)), [damaged, "`scale` must be positive"]),
        ("degree 5", put(degree=np.array(5)), [damaged, "`degree`", "[-1, 1]"]),
        ("float degree", put(degree=np.array(0.5)), [damaged, "`degree`", "whole numbers"]),
        ("unknown kernel", put(kernel=np.array("magic")), [damaged, "unknown kernel 'magic'"]),
        ("kernel number", put(kernel=np.array(3.0)), [damaged, "`kernel`", "text"]),
        ("missing weights", drop("weights"), [damaged, "`weights` is missing"]),
        ("short weights", weights(lambda w: w[:-1]), [damaged, "shape (19,)", "(20,)"]),
        ("unknown kind", put(kind=np.array("octree")), [damaged, "`kind`"]),
        ("newer format", put(format_version=np.array(99)), ["newer jaxrbf", "model format 99"]),
        ("foreign", lambda d: {"points": d["centres"]}, ["is not a jaxrbf model", "points"]),
        ("other format", put(format=np.array("other-tool")), ["is not a jaxrbf model", "other"]),
    ]


@pytest.mark.parametrize(
    "change, words", [c[1:] for c in _model_cases()], ids=[c[0] for c in _model_cases()]
)
def test_model_fields_validated(tmp_path, capsys, model_fields, change, words):
    path = tmp_path / "model.npz"
    np.savez(path, **change(dict(model_fields)))
    with pytest.raises(InputError) as e:
        jaxrbf.load(path)
    for word in words:
        assert word in str(e.value), (word, str(e.value))
    refuse(capsys, tmp_path, "mesh", path, words=words)


@pytest.mark.parametrize(
    "content, words",
    [
        (b"hello, I am text\n", ["is not a jaxrbf model", "not an .npz archive"]),
        (npy_bytes((3,), body=b"\0" * 24), ["is not a jaxrbf model"]),
        (b"", ["empty file", "truncated or corrupt"]),
        (b"PK\x03\x04" + b"\0" * 40, ["truncated or corrupt"]),
    ],
    ids=["text", "npy", "empty", "broken zip"],
)
def test_files_that_are_no_model(tmp_path, capsys, content, words):
    path = tmp_path / "model.npz"
    path.write_bytes(content)
    with pytest.raises(InputError) as e:
        jaxrbf.load(path)
    for word in words:
        assert word in str(e.value)
    refuse(capsys, tmp_path, "mesh", path, words=words)
    refuse(capsys, tmp_path, "render", path, words=words, ext=".png")


def test_truncated_model(tmp_path, capsys, model_files):
    data = (model_files / "m3.npz").read_bytes()
    path = tmp_path / "cut.npz"
    path.write_bytes(data[: len(data) // 2])
    refuse(capsys, tmp_path, "mesh", path, words=["truncated or corrupt"])


def test_model_called_with_the_wrong_dimension(model_files):
    model = jaxrbf.load(model_files / "m3.npz")
    with pytest.raises(InputError, match=r"shape \(\.\.\., 3\) for this 3-D model"):
        model(np.zeros((4, 2)))


# --------------------------------------------------------------------------- 3. inputs that were
# accepted although they must be refused, and messages that sent the user the wrong way


def test_ascii_ply_with_fewer_faces_than_declared(tmp_path, capsys):
    v, f = icosahedron()
    path = tmp_path / "short.ply"
    path.write_bytes(ascii_ply(v, f[:30], declared_faces=len(f)))
    with pytest.raises(InputError, match=f"declares {len(f)} faces but the file holds 30"):
        io.read_mesh(path)
    refuse(capsys, tmp_path, "reconstruct", path, words=[f"declares {len(f)} faces", "holds 30"])


@pytest.mark.parametrize(
    "name, content, words",
    [
        ("cut.stl", "binary stl, cut", ["cut.stl", "truncated"]),
        ("noise.stl", bytes(range(50)), ["noise.stl", "not an STL file"]),
        ("ascii.stl", b"solid x\n facet normal 0 0 1\n  outer loop\n   vertex 1 2\n", ["facet"]),
        ("binary.obj", b"\x7fELF\0\0\0" + bytes(range(256)), ["binary.obj", "binary data"]),
        ("words.obj", b"this is\nnot a mesh\n", ["words.obj", "holds no vertices", "not an OBJ"]),
        ("v2.obj", b"v 0 0 0\nv 1 0\n", ["v2.obj", "line 2", "3 coordinates"]),
        ("vx.obj", b"v 0 0 0\nv 1 0 x\nf 1 2 1\n", ["vx.obj", "line 2", "not a number"]),
        ("counts.off", b"OFF\n3 one 0\n", ["counts.off", "line 2", "counts"]),
        ("short.off", b"OFF\n3 1 0\n0 0 0\n1 0 0\n", ["short.off", "declares 3 vertices"]),
        ("face.off", b"OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1\n", ["face.off", "line 6"]),
        ("header.ply", b"ply\nformat ascii 1.0\nelement vertex x\n", ["header.ply", "line 3"]),
        ("endless.ply", b"ply\nformat ascii 1.0\nelement vertex 3\n", ["never ends"]),
        ("notply.ply", b"PLY file?\n", ["notply.ply", "not a PLY file"]),
        ("text.npz", b"x y z\n0 0 0\n", ["text.npz", "not an .npz archive"]),
        ("array.npz", npy_bytes((1, 3), body=b"\0" * 24), ["array.npz", "single .npy array"]),
        ("objects.npy", npy_bytes((2,), "|O", b"\x80\x04N."), ["objects.npy", "Python objects"]),
        ("complex.npy", npy_bytes((2, 2), "<c16", b"\0" * 64), ["complex.npy", "complex"]),
        ("row.xyz", b"0 0 0\n1 1 1\n\n1 2 abc\n", ["row.xyz", "line 4", "'abc' is not a number"]),
        ("ragged.xyz", b"0 0 0\n1 1 1\n1 2 3 4\n", ["ragged.xyz", "line 3 holds 4 numbers"]),
        ("binary.xyz", b"\0\1\2\3" * 20, ["binary.xyz", "binary data"]),
        ("row.csv", b"x,y\n0,0\n1,1\n2,two\n", ["row.csv", "line 4", "'two'"]),
    ],
)
def test_broken_files_named_for_what_is_wrong(tmp_path, capsys, name, content, words):
    if content == "binary stl, cut":
        import trimesh

        v, f = icosahedron()
        content = trimesh.Trimesh(v, f, process=False).export(file_type="stl")[:300]
    path = tmp_path / name
    path.write_bytes(content)
    with pytest.raises(InputError) as e:
        io.read_input(path)
    message = str(e.value)
    for word in words:
        assert word in message, (word, message)
    assert " is empty" not in message
    assert message.count("could not be read as") <= 1
    refuse(capsys, tmp_path, "reconstruct", path, words=words)


@pytest.mark.parametrize(
    "scale, words",
    [
        (1e200, ["too large for float64", "rescale"]),
        (1e-300, ["too small for float64", "rescale"]),
    ],
)
def test_coordinates_beyond_float64(tmp_path, capsys, scale, words):
    p, n = sphere(200)
    path = tmp_path / "cloud.xyz"
    np.savetxt(path, np.hstack([p * scale, n]))
    err = refuse(capsys, tmp_path, "reconstruct", path, words=words, quick=True)
    assert "offset" not in err and "same point" not in err
    with pytest.raises(InputError, match=words[0]):
        jaxrbf.reconstruct(p * scale, n)
    with pytest.raises(InputError, match="cannot resolve"):
        io.as_points(p * 1e-3 + 1e10)  # differences lost to rounding


def test_too_few_points(tmp_path, capsys):
    for n, words in ((1, ["only 1 point"]), (3, ["only 3 points", "at least 4"])):
        path = tmp_path / f"p{n}.xyz"
        np.savetxt(path, np.hstack([np.eye(3)[:n], np.tile([0, 0, 1.0], (n, 1))]))
        err = refuse(capsys, tmp_path, "reconstruct", path, words=words)
        assert f"all {n}" not in err
    rng = np.random.default_rng(0)
    path = tmp_path / "six.xyz"
    np.savetxt(path, rng.normal(size=(6, 3)))
    err = refuse(
        capsys, tmp_path, "reconstruct", path, "--remove-outliers", words=["give more points"]
    )
    assert "(lower `k`)" not in err


# --------------------------------------------------------------------------- 4. output paths


def test_output_paths_checked_before_any_work(tmp_path, capsys, model_files):
    model = model_files / "m3.npz"
    folder = tmp_path / "adir.ply"
    folder.mkdir()
    code, err, _ = cli(capsys, "mesh", model, "-o", folder, "--resolution", "16")
    assert_refused(code, err, str(folder), "is a folder")
    assert os.listdir(folder) == [] and sorted(os.listdir(tmp_path)) == ["adir.ply"]

    long = tmp_path / ("x" * 300 + ".ply")
    code, err, _ = cli(capsys, "mesh", model, "-o", long)
    assert_refused(code, err, "file name is 304 bytes long", "x" * 300)

    for out, words in (
        (tmp_path / "nope" / "o.ply", ["nope", "does not exist"]),
        (tmp_path / "o.docx", ["o.docx", "unsupported format '.docx'"]),
        (tmp_path / "noext", ["noext", "no extension"]),
    ):
        code, err, _ = cli(capsys, "mesh", model, "-o", out)
        assert_refused(code, err, *words)
    code, err, _ = cli(capsys, "render", model, "-o", tmp_path / "view.jpg")
    assert_refused(code, err, "view.jpg", ".png")
    p, n = sphere(50)
    np.savetxt(tmp_path / "ball.xyz", np.hstack([p, n]))
    code, err, _ = cli(
        capsys, "reconstruct", tmp_path / "ball.xyz", "-o", tmp_path / "o.ply", "--preview", folder
    )
    assert_refused(code, err, "--preview", "is a folder")
    assert sorted(os.listdir(tmp_path)) == ["adir.ply", "ball.xyz"]


@pytest.mark.skipif(os.geteuid() == 0, reason="root may write into any folder")
def test_read_only_output_folder(tmp_path, capsys, model_files):
    folder = tmp_path / "ro"
    folder.mkdir()
    folder.chmod(0o500)
    try:
        code, err, _ = cli(capsys, "mesh", model_files / "m3.npz", "-o", folder / "o.ply")
        assert_refused(code, err, "is not writable")
    finally:
        folder.chmod(0o700)


def test_long_output_name_gets_a_short_temporary_file(tmp_path):
    """A name that fits, but would not with the temporary file's suffix, is still written."""
    v, f = icosahedron()
    out = tmp_path / ("m" * 250 + ".ply")
    io.write_mesh(out, v, f)
    assert os.listdir(tmp_path) == [out.name]
    np.testing.assert_array_equal(io.read_mesh(out).faces, f)


# --------------------------------------------------------------------------- 5. PLY elements


def test_tristrips_decoded_into_triangles(tmp_path, capsys):
    """A strip with a -1 restart and alternate winding: the triangles of a 2 x 2 quad grid and one
    more, all facing +z, and the elements and properties jaxrbf does not use named on stderr."""
    vertices = [[x, y, 0.0, 7] for y in (0, 1, 2) for x in (0, 1, 2)]
    head = ply_header(
        "ascii",
        [
            ("vertex", 9, XYZ + ["uchar red"]),
            ("tristrips", 1, ["list int int vertex_indices"]),
            ("edge", 1, ["int vertex1", "int vertex2"]),
        ],
    )
    body = [" ".join(map(str, v)) for v in vertices]
    body += ["11 0 3 1 4 2 5 -1 3 6 4 7", "0 1"]
    path = tmp_path / "strips.ply"
    path.write_bytes(head + ("\n".join(body) + "\n").encode())
    mesh = io.read_input(path)
    err = capsys.readouterr().err
    assert isinstance(mesh, io.Mesh) and len(mesh.faces) == 6
    tri = mesh.vertices[mesh.faces]
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    # the first triangle's winding (0, 3, 1) faces -z, and so does every other one
    assert np.allclose(normals, [0, 0, -1])
    assert "not used" in err and "red" in err and "'edge'" in err


def test_binary_tristrips(tmp_path):
    """The same strip in a binary PLY (one strip: trimesh reads its list), and one cut short."""
    grid = np.array([[x, y, 0.0] for y in (0, 1, 2) for x in (0, 1, 2)], "<f4")
    strip = np.array([11, 0, 3, 1, 4, 2, 5, -1, 3, 6, 4, 7], "<i4")
    head = ply_header(
        "binary_little_endian",
        [("vertex", 9, XYZ), ("tristrips", 1, ["list int int vertex_indices"])],
    )
    path = tmp_path / "strips.ply"
    path.write_bytes(head + grid.tobytes() + strip.tobytes())
    mesh = io.read_mesh(path)
    tri = mesh.vertices[mesh.faces]
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    assert len(mesh.faces) == 6 and np.allclose(normals, [0, 0, -1])
    path.write_bytes(head + grid.tobytes() + strip.tobytes()[:-4])
    with pytest.raises(InputError, match="strips.ply' could not be read as PLY"):
        io.read_mesh(path)


def test_unused_ply_properties_named_but_the_file_read(tmp_path, capsys):
    v, f = icosahedron()
    head = ply_header("ascii", [("vertex", len(v), XYZ + ["float confidence"]), ("face", 0, FACE)])
    path = tmp_path / "scan.ply"
    path.write_bytes(head + "".join(f"{a} {b} {c} 0.5\n" for a, b, c in v).encode())
    cloud = io.read_input(path)
    assert isinstance(cloud, io.PointCloud) and len(cloud.points) == len(v)
    assert "vertex properties confidence" in capsys.readouterr().err


# --------------------------------------------------------------------------- the installed script


def _script(*argv, cwd):
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path), JAX_PLATFORMS="cpu")
    return subprocess.run(
        [sys.executable, "-m", "jaxrbf.cli", *map(str, argv)],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=cwd,
        env=env,
    )


@pytest.mark.slow
def test_script_hostile_size_and_bad_option(tmp_path):
    (tmp_path / "huge.npz").write_bytes(b"")
    with zipfile.ZipFile(tmp_path / "huge.npz", "w") as z:
        z.writestr("points.npy", npy_bytes((HUGE, 3)))
    (tmp_path / "out.ply").write_bytes(PRECIOUS)
    t0 = time.perf_counter()
    r = _script("reconstruct", "huge.npz", "-o", "out.ply", cwd=tmp_path)
    assert time.perf_counter() - t0 < 60
    assert_refused(r.returncode, r.stderr, "huge.npz", "truncated")
    r = _script("reconstruct", "huge.npz", "-o", "out.ply", "--points", "many", cwd=tmp_path)
    assert_refused(r.returncode, r.stderr, "--points", "invalid int value: 'many'")
    assert (tmp_path / "out.ply").read_bytes() == PRECIOUS
    assert sorted(os.listdir(tmp_path)) == ["huge.npz", "out.ply"]


@pytest.mark.parametrize("repeated", [150, 500])  # some points twice, and every one
def test_repeated_points_of_a_bare_cloud_are_kept_once(capsys, repeated):
    # a bare cloud with positions given twice (scans merged where they overlap, a file written
    # out twice): merged before anything counts neighbours. Before, every point twice was
    # refused by the noise estimate ("more than half of the points have a duplicate"), and 30%
    # of them twice made a closed sphere read as full of holes
    from jaxrbf import surface_from

    p, _ = sphere(500)
    cloud = np.vstack([p, p[:repeated]])
    q, n, _ = surface_from(cloud, remove_outliers="auto", verbose=True)
    assert len(q) == 500 and len(np.unique(q, axis=0)) == 500
    assert f"{repeated:,} repeated points" in capsys.readouterr().err
    assert np.all(np.einsum("ij,ij->i", n, q) > 0.9)  # normals estimated and turned outward
