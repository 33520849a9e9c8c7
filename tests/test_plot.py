"""2-D field pictures (the paper's Fig. 4) through matplotlib."""

import sys

import numpy as np
import pytest
from helpers import ellipse

import jaxrbf
from jaxrbf import csg

pytest.importorskip("matplotlib")


@pytest.fixture(scope="module")
def fitted():
    c = jaxrbf.Constraints.from_polyline(ellipse(40, closed_repeat=True), offset=0.2)
    return c, jaxrbf.fit(c, kernel="thin-plate")


def test_field_zero_contour_and_constraints(fitted, tmp_path):
    import matplotlib.pyplot as plt

    c, model = fitted
    out = tmp_path / "field.png"
    ax = jaxrbf.plot_field(model, constraints=c, levels=6, resolution=120, path=out, title="f")
    assert out.exists() and out.stat().st_size > 1000
    # the thick black contour is f = 0: its vertices lie on the fitted curve
    zero = [cs for cs in ax.collections if getattr(cs, "levels", None) is not None]
    levels = [list(cs.levels) for cs in zero]
    assert [0.0] in levels and any(len(lv) == 6 for lv in levels)
    zc = zero[levels.index([0.0])]
    verts = np.concatenate([p.vertices for p in zc.get_paths() if len(p.vertices)])
    spacing = 2 * 2.4 / 120
    assert np.abs(np.asarray(model(verts))).max() < 0.05 * spacing * 10
    # the markers: as many as there are constraints of each kind
    v = np.asarray(c.values)
    counts = {
        cs.get_label(): len(cs.get_offsets()) for cs in ax.collections if cs.get_label()[0] != "_"
    }
    assert counts == {
        "on (0)": int((v == 0).sum()),
        "outside (> 0)": int((v > 0).sum()),
        "inside (< 0)": int((v < 0).sum()),
    }
    plt.close(ax.figure)


def test_csg_shape_into_given_axes():
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots()
    shape = csg.Box((0, 0), (1.0, 0.5)) - csg.Sphere((1.0, 0.5), 0.4)
    assert jaxrbf.plot_field(shape, ax=ax, levels=[-0.2, 0.2], colorbar=False) is ax
    lo, hi = ax.get_xlim(), ax.get_ylim()
    assert lo[0] < -1 and lo[1] > 1 and hi[0] < -0.5 and hi[1] > 0.5
    plt.close(fig)


def test_bad_input(fitted, tmp_path, monkeypatch):
    _, model = fitted
    with pytest.raises(jaxrbf.InputError, match=r"\.gif"):
        jaxrbf.plot_field(model, path=tmp_path / "f.gif")
    with pytest.raises(jaxrbf.InputError, match="2-D"):
        jaxrbf.plot_field(csg.Sphere())
    with pytest.raises(jaxrbf.InputError, match="constraints"):
        jaxrbf.plot_field(model, constraints=np.zeros((3, 2)))
    monkeypatch.setitem(sys.modules, "matplotlib", None)
    with pytest.raises(jaxrbf.InputError, match="matplotlib"):
        jaxrbf.plot_field(model)
    assert not list(tmp_path.iterdir())
