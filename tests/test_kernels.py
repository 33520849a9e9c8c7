import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxrbf import InputError, kernels
from jaxrbf.kernels import KERNELS, make_kernel

RADIUS = {True: 0.7, False: None}
ALL = [make_kernel(name, RADIUS[cls.has_radius]) for name, cls in KERNELS.items()]


@pytest.mark.parametrize("k", ALL, ids=lambda k: k.name)
def test_finite_value_and_gradient_at_zero(k):
    assert np.isfinite(float(k(0.0)))
    # gradient of phi(|x - c|) with respect to x at x = c, through the squared-distance form
    g = jax.grad(lambda x: k.from_r2(jnp.sum(x * x)))(jnp.zeros(3))
    assert np.all(np.isfinite(np.asarray(g)))


@pytest.mark.parametrize(
    "name, fn",
    [
        ("linear", lambda r, R: -r),
        ("cubic", lambda r, R: r**3),
        ("thin-plate", lambda r, R: r**2 * np.log(r)),
        ("gaussian", lambda r, R: np.exp(-((r / R) ** 2))),
        ("multiquadric", lambda r, R: -np.sqrt(1 + (r / R) ** 2)),
        ("inverse-multiquadric", lambda r, R: 1 / np.sqrt(1 + (r / R) ** 2)),
        ("wendland", lambda r, R: np.clip(1 - r / R, 0, None) ** 4 * (4 * r / R + 1)),
    ],
)
def test_values_match_their_formulas(name, fn):
    R = 0.7
    k = make_kernel(name, R if KERNELS[name].has_radius else None)
    r = np.array([0.05, 0.3, 0.69, 0.71, 2.0])
    np.testing.assert_allclose(np.asarray(k(r)), fn(r, R), rtol=1e-12)


def test_wendland_is_compactly_supported():
    k = kernels.Wendland(0.5)
    assert float(k(0.5)) == 0.0 and float(k(0.75)) == 0.0 and float(k(0.49)) > 0


@pytest.mark.parametrize(
    "name, degree, pd",
    [
        ("linear", 0, False),
        ("cubic", 1, False),
        ("thin-plate", 1, False),
        ("gaussian", -1, True),
        ("multiquadric", 0, False),
        ("inverse-multiquadric", -1, True),
        ("wendland", -1, True),
    ],
)
def test_metadata(name, degree, pd):
    assert KERNELS[name].min_degree == degree
    assert KERNELS[name].positive_definite is pd


@pytest.mark.parametrize("name", ["gaussian", "inverse-multiquadric", "wendland"])
def test_positive_definite_kernels_give_positive_definite_matrices(name):
    x = np.random.default_rng(0).random((60, 3))
    k = make_kernel(name, 0.4)
    a = np.asarray(k(np.linalg.norm(x[:, None] - x[None], axis=-1)))
    assert np.linalg.eigvalsh(a).min() > 0


def test_radius_is_differentiable():
    g = jax.grad(lambda R: kernels.Gaussian(R)(0.5))(1.0)
    assert np.isclose(float(g), 2 * 0.25 * np.exp(-0.25))


def test_errors():
    with pytest.raises(InputError, match="unknown kernel 'bogus'"):
        make_kernel("bogus")
    with pytest.raises(InputError, match="needs a `radius`"):
        make_kernel("gaussian")
    with pytest.raises(InputError, match="has no radius"):
        make_kernel("cubic", 0.5)
    with pytest.raises(InputError, match="positive finite"):
        kernels.Gaussian(-1.0)
    assert isinstance(make_kernel("thin_plate_spline"), kernels.ThinPlate)
