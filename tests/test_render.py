"""Ray-marched pictures: silhouettes and depths against closed forms and rasterised meshes, hit
points on f = 0, shading options, PNG output, the camera's input checks and the CLI."""

import jax.numpy as jnp
import numpy as np
import pytest
from conftest import data_file
from helpers import sphere

import jaxrbf
from jaxrbf import csg
from jaxrbf.cli import main
from jaxrbf.render import Camera

CENTRE = np.array([0.1, -0.05, 0.0])
RADIUS = 0.8


def closed_form_sphere(camera):
    """Hit mask and depth of the rays of `camera` against the sphere (CENTRE, RADIUS)."""
    o, d = camera.rays()
    oc = o - CENTRE
    b = -np.sum(oc * d, axis=1)
    disc = b * b - (np.sum(oc * oc, axis=1) - RADIUS**2)
    hit = (disc > 0) & (b > 0)
    depth = np.where(hit, b - np.sqrt(np.maximum(disc, 0)), np.inf)
    shape = (camera.height, camera.width)
    return hit.reshape(shape), depth.reshape(shape)


def iou(a, b):
    return (a & b).sum() / (a | b).sum()


@pytest.fixture(scope="module")
def ball_picture():
    camera = Camera((0.7, 0.9, 3.0), (0.0, 0.0, 0.0), fov=40, size=(112, 96))
    return camera, jaxrbf.render(csg.Sphere(CENTRE, RADIUS), camera, progress=False)


def test_sphere_matches_closed_form_silhouette_and_depth(ball_picture):
    camera, pic = ball_picture
    hit, depth = closed_form_sphere(camera)
    assert pic.image.shape == (96, 112, 3) and pic.image.dtype == np.uint8
    assert iou(hit, pic.hit) > 0.99
    both = hit & pic.hit
    np.testing.assert_allclose(pic.depth[both], depth[both], rtol=0, atol=1e-7)
    assert np.all(np.isinf(pic.depth[~pic.hit]))
    # hit points on f = 0, normals radial
    p, n = pic.points[pic.hit], pic.normals[pic.hit]
    np.testing.assert_allclose(np.linalg.norm(p - CENTRE, axis=1), RADIUS, atol=1e-9)
    np.testing.assert_allclose(n, (p - CENTRE) / RADIUS, atol=1e-7)
    assert pic.stats["unconverged"] == 0 and pic.stats["unfinished"] == 0
    # background pixels keep the background, surface pixels are shaded differently
    assert not np.array_equal(pic.image[pic.hit][0], pic.image[~pic.hit][0])


def test_any_callable_with_bounds_and_bounding_box_skip():
    camera = Camera((0.0, 0.0, 4.0), (0.0, 0.0, 0.0), fov=30, size=(48, 40))
    with pytest.raises(jaxrbf.InputError, match="bounds"):
        jaxrbf.render(lambda x: x[:, 0], camera)
    g = lambda x: jnp.linalg.norm(x - CENTRE, axis=-1) - RADIUS  # noqa: E731
    pic = jaxrbf.render(g, camera, bounds=(CENTRE - 1, CENTRE + 1), progress=False)
    hit, _ = closed_form_sphere(camera)
    assert iou(hit, pic.hit) > 0.99
    assert pic.stats["box_rays"] < pic.stats["rays"]  # rays missing the box were never marched


def rasterise(mesh, camera):
    """Silhouette of a triangle mesh seen by `camera` (pixel centres inside projected faces)."""
    from skimage.draw import polygon

    rows, cols, z = camera.project(mesh.vertices)
    mask = np.zeros((camera.height, camera.width), bool)
    assert np.all(z > 0)
    for tri in mesh.faces:
        rr, cc = polygon(rows[tri], cols[tri], shape=mask.shape)
        mask[rr, cc] = True
    return mask


@pytest.mark.slow
def test_reconstructed_mesh_silhouette_matches_the_original(tmp_path):
    path = data_file("spot.obj")
    model = jaxrbf.fit_surface(str(path), points=1000)
    mesh = jaxrbf.io.read_mesh(path)
    camera = Camera.orbit(_box(mesh), 40, 15, size=(96, 96))
    pic = jaxrbf.render(model, camera, progress=False)
    reference = rasterise(mesh, camera)
    assert reference.sum() > 1500  # the model fills a good part of the picture
    assert iou(reference, pic.hit) > 0.97
    f = np.asarray(model(pic.points[pic.hit]))
    assert np.abs(f).max() < 1e-8
    out = tmp_path / "spot.png"
    pic.save(out)
    from PIL import Image

    with Image.open(out) as im:
        assert im.size == (96, 96)
        np.testing.assert_array_equal(np.asarray(im.convert("RGB")), pic.image)


def _box(mesh):
    v = np.asarray(mesh.vertices)
    return v.min(axis=0), v.max(axis=0)


def test_shadows_occlusion_and_colour_by_scalar():
    scene = csg.Box((0, -0.7, 0), (1.5, 0.1, 1.5)) | csg.Sphere((0, 0.2, 0), 0.5)
    camera = Camera.orbit(scene, 20, 35, size=(64, 64))
    plain = jaxrbf.render(scene, camera, progress=False)
    shaded = jaxrbf.render(scene, camera, shadows=True, ambient_occlusion=True, progress=False)
    np.testing.assert_array_equal(plain.hit, shaded.hit)
    on_floor = plain.hit & (plain.points[..., 1] < -0.55)
    darker = shaded.image.astype(int).sum(-1) < plain.image.astype(int).sum(-1) - 30
    assert darker[on_floor].sum() > 20  # the ball's shadow and occlusion darken the floor
    ball = csg.Sphere(CENTRE, RADIUS)
    curved = jaxrbf.render(ball, camera, color_by="curvature", progress=False)
    np.testing.assert_allclose(curved.scalar[curved.hit], 1 / RADIUS, rtol=1e-6)
    assert np.all(np.isnan(curved.scalar[~curved.hit]))
    mesh = jaxrbf.polygonize(ball, resolution=48)
    err = jaxrbf.render(ball, camera, color_by=jaxrbf.mesh_error(mesh, n=50_000), progress=False)
    assert np.abs(err.scalar[err.hit]).max() < 0.02  # marching cubes' chords vs the sphere
    with pytest.raises(jaxrbf.InputError, match="color_by"):
        jaxrbf.render(ball, camera, color_by="bumpiness")


def test_mean_curvature_of_a_torus():
    torus = csg.Torus((0, 0, 0), 1.0, 0.3)
    p = np.array([[1.3, 0.0, 0.0], [0.7, 0.0, 0.0]])  # outer and inner equator
    h = jaxrbf.mean_curvature(torus, p)
    # principal curvatures 1/r and cos(v)/(R + r cos v)
    np.testing.assert_allclose(h, [(1 / 0.3 + 1 / 1.3) / 2, (1 / 0.3 - 1 / 0.7) / 2], rtol=1e-9)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(position=(np.nan, 0, 0), target=(0, 0, 0)), "position"),
        (dict(position=(1, 2, 3), target=(1, 2, 3)), "target"),
        (dict(position=(0, 0, 3), target=(0, 0, 0), size=(0, 10)), "size"),
        (dict(position=(0, 0, 3), target=(0, 0, 0), size=(10,)), "size"),
        (dict(position=(0, 0, 3), target=(0, 0, 0), fov=180), "fov"),
        (dict(position=(0, 3, 0), target=(0, 0, 0), up="y"), "parallel"),
        (dict(position=(0, 0, 3), target=(0, 0, 0), up="w"), "up"),
    ],
)
def test_camera_rejects_bad_input(kwargs, match):
    with pytest.raises(jaxrbf.InputError, match=match):
        Camera(**kwargs)


def test_bad_render_arguments(tmp_path):
    ball = csg.Sphere((0, 0, 0), 1.0)
    with pytest.raises(jaxrbf.InputError, match="elevation"):
        Camera.orbit(ball, 0, 90)
    with pytest.raises(jaxrbf.InputError, match="unbounded"):
        jaxrbf.render(csg.Plane(), Camera((0, 0, 3), (0, 0, 0)))
    with pytest.raises(jaxrbf.InputError, match="2-D"):
        jaxrbf.render(csg.Sphere((0, 0), 1.0), Camera((0, 0, 3), (0, 0, 0)))
    with pytest.raises(jaxrbf.InputError, match=r"\.jpg"):
        jaxrbf.save_png(tmp_path / "x.jpg", np.zeros((4, 4, 3), np.uint8))
    with pytest.raises(jaxrbf.InputError, match="image"):
        jaxrbf.save_png(tmp_path / "x.png", np.zeros((0, 4, 3), np.uint8))
    assert not list(tmp_path.iterdir())


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.mark.slow
def test_cli_render_and_preview(tmp_path, capsys):
    p, n = sphere(200, radius=0.5)
    src = tmp_path / "ball.xyz"
    np.savetxt(src, np.hstack([p, n]))
    model = tmp_path / "ball.npz"
    assert run(capsys, "fit", src, "-o", model, "-q")[0] == 0
    view = tmp_path / "view.png"
    code, _, err = run(
        capsys, "render", model, "-o", view, "--size", 40, 30, "--azimuth", 10,
        "--elevation", 30, "--shadows",
    )  # fmt: skip
    assert code == 0, err
    assert "wrote" in err
    from PIL import Image

    with Image.open(view) as im:
        assert im.size == (40, 30)
    code, _, err = run(capsys, "render", model, "-o", tmp_path / "view.jpg")
    assert code == 2 and err.startswith("jaxrbf: error:") and ".jpg" in err
    bad = tmp_path / "broken.npz"
    bad.write_bytes(b"not a model")
    code, _, err = run(capsys, "render", bad, "-o", view)
    assert code == 2 and err.startswith("jaxrbf: error:")
    code, _, err = run(capsys, "render", model, "-o", view, "--size", 0, 10)
    assert code == 2 and "size" in err
    mesh, preview = tmp_path / "ball.ply", tmp_path / "preview.png"
    code, _, err = run(
        capsys, "reconstruct", src, "-o", mesh, "--resolution", 24, "--preview", preview, "-q"
    )
    assert code == 0, err
    assert mesh.exists() and preview.exists()
