"""The overlapping decomposition and the Schwarz-preconditioned CG / GMRES solvers."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import sphere, torus

import jaxrbf
from jaxrbf import SolveError
from jaxrbf._model import poly_basis
from jaxrbf._schwarz import decompose
from jaxrbf._solve import _null_space_matrix, _projector, schwarz_preconditioner, solve_system
from jaxrbf._system import kernel_matrix
from jaxrbf.kernels import make_kernel


def _surface_constraints(n=700):
    pts, nrm = sphere(n)
    return jaxrbf.Constraints.from_points(pts, nrm, offset=0.05)


def _torus_constraints():
    pts, nrm = torus(50, 14)
    return jaxrbf.Constraints.from_points(pts, nrm, offset=0.03)


def _torus_system(**split):
    """Arguments of `solve_system` for the torus in the unit box (cubic kernel, degree 1)."""
    c = _torus_constraints()
    x = jnp.asarray(c.points)
    x = (x - x.min(0)) / jnp.max(x.max(0) - x.min(0))
    d = tuple(jnp.asarray(a) for a in decompose(np.asarray(x), **split))
    return make_kernel("cubic"), x, jnp.asarray(c.values), jnp.asarray(0.0), 1, d


# --- decomposition ---------------------------------------------------------------------------


def test_decompose_covers_overlaps_and_pads():
    x = np.random.default_rng(0).random((2000, 3))
    d = decompose(x, leaf=300, overlap=10, coarse=100)
    assert d.n_subdomains == 7  # ceil(2000 / 300) leaves
    members = [set(d.idx[s][d.mask[s]].tolist()) for s in range(d.n_subdomains)]
    assert set().union(*members) == set(range(2000))
    # neighbours are shared: the subdomains hold more than the n points between them
    assert sum(len(m) for m in members) > 2000
    assert all(len(m) >= 2000 // 7 for m in members)
    assert np.all(d.idx[~d.mask] == 0)  # padding points at a valid index and is masked out
    assert len(d.coarse) == 100 and len(set(d.coarse.tolist())) == 100


def test_decompose_is_spatially_compact():
    x = np.random.default_rng(1).random((4000, 3))
    d = decompose(x, leaf=500, overlap=1, coarse=0)
    # with no overlap each subdomain is one k-d cell, far smaller than the whole box
    for s in range(d.n_subdomains):
        ext = np.ptp(x[d.idx[s][d.mask[s]]], axis=0)
        assert np.prod(ext) < 0.3
    assert len(d.coarse) == 0


def test_small_input_is_one_subdomain():
    x = np.random.default_rng(2).random((100, 2))
    d = decompose(x, leaf=500)
    assert d.n_subdomains == 1 and d.mask.all() and len(d.coarse) == 0


# --- the preconditioner ----------------------------------------------------------------------


def test_preconditioner_is_symmetric_positive_definite():
    c = _surface_constraints(300)
    x = jnp.asarray(c.points)
    kernel = make_kernel("cubic")
    q1, _ = _projector(poly_basis(x, 1))
    d = tuple(jnp.asarray(a) for a in decompose(np.asarray(x), leaf=200, overlap=10, coarse=60))

    @jax.jit
    def dense_preconditioner(x, q1, d):
        return jax.vmap(schwarz_preconditioner(kernel, x, 1, 0.0, d, q1))(jnp.eye(len(x))).T

    m_inv = np.asarray(dense_preconditioner(x, q1, d))
    np.testing.assert_allclose(m_inv, m_inv.T, atol=1e-9 * np.abs(m_inv).max())
    assert np.linalg.eigvalsh(m_inv).min() > 0
    # and it is a good one: the preconditioned system is far better conditioned than C
    c_mat = np.asarray(_null_space_matrix(kernel_matrix(kernel, x, 0.0), q1))
    ev_c = np.linalg.eigvalsh(c_mat)
    ev_pc = np.sort(np.abs(np.linalg.eigvals(m_inv @ c_mat)))
    assert ev_pc[-1] / ev_pc[0] < 1e-3 * ev_c[-1] / ev_c[0]


@pytest.mark.slow
def test_preconditioner_cuts_iterations():
    kernel, x, h, s, degree, d = _torus_system(leaf=300)
    pre = solve_system(kernel, x, h, s, degree, "cg", 1e-10, 2000, d)
    plain = solve_system(kernel, x, h, s, degree, "cg", 1e-10, 2000, None)
    assert bool(pre.ok) and float(pre.residual) < 1e-7
    assert int(pre.steps) < 100
    assert int(pre.steps) * 5 < int(plain.steps)


# --- through fit -----------------------------------------------------------------------------


@pytest.mark.slow
@pytest.mark.parametrize(
    "solver, kernel, radius",
    [
        ("cg", "cubic", None),
        ("cg", "thin-plate", None),
        ("cg", "multiquadric", 0.5),
        ("cg", "wendland", 0.5),
        ("gmres", "cubic", None),
    ],
)
def test_iterative_solvers_match_lu_on_many_subdomains(solver, kernel, radius):
    c = _torus_constraints()  # 2,100 constraints: several subdomains of the default size
    ref = jaxrbf.fit(c, kernel=kernel, radius=radius, solver="lu")
    model = jaxrbf.fit(c, kernel=kernel, radius=radius, solver=solver)
    assert float(model.residual) < 1e-7
    q = np.random.default_rng(3).uniform(-1.4, 1.4, (500, 3))
    np.testing.assert_allclose(np.asarray(model(q)), np.asarray(ref(q)), atol=1e-6)


def test_cg_reports_iterations(capsys):
    jaxrbf.fit(_surface_constraints(), solver="cg", verbose=True)
    err = capsys.readouterr().err
    assert "CG iterations" in err and "relative residual" in err


def test_cg_iteration_cap():
    with pytest.raises(SolveError, match="cg stopped after 2 iterations"):
        jaxrbf.fit(_torus_constraints(), solver="cg", max_steps=2)


@pytest.mark.slow
def test_matrix_free_cg_matches_stored():
    # above the dense limit CG applies C block by block instead of storing it: same answer
    kernel, x, h, s, degree, d = _torus_system()
    args = (kernel, x, h, s, degree, "cg", 1e-11, 500, d)
    stored = solve_system(*args, stored=True)
    free = solve_system(*args, stored=False)
    assert bool(free.ok) and float(free.residual) < 1e-7
    w_free, w_stored = np.asarray(free.weights), np.asarray(stored.weights)
    np.testing.assert_allclose(w_free, w_stored, atol=1e-5 * np.abs(w_stored).max())
