"""Greedy centre reduction (Carr et al. 2001): `jaxrbf._greedy.greedy_fit`."""

import numpy as np
import pytest
from helpers import sphere

import jaxrbf
from jaxrbf import InputError
from jaxrbf._greedy import GreedyReport, _spread, greedy_fit

OFFSET = 0.05


def _sphere_constraints(n=300):
    pts, nrm = sphere(n)
    return jaxrbf.Constraints.from_points(pts, nrm, offset=OFFSET)


C = _sphere_constraints()  # 900 constraints: values 0 and +/- 0.05
X, H = np.asarray(C.points), np.asarray(C.values)
N = len(X)


def _check_report(rep: GreedyReport, model):
    sizes = [r.centres for r in rep.rounds]
    assert sizes == sorted(set(sizes)), "every round adds centres"
    assert rep.n_centres == sizes[-1] == len(rep.centre_indices) == model.centres.shape[0]
    assert rep.n_points == N
    assert all(r.seconds >= 0 and r.solve_residual < 1e-6 for r in rep.rounds)
    assert all(r.n_above > 0 for r in rep.rounds[:-1]), "it stops once every residual <= tol"
    # the centres are the chosen points (in the model's normalised frame)
    world = np.asarray(model.centres * model.scale + model.shift)
    np.testing.assert_allclose(world, X[rep.centre_indices], atol=1e-12)
    # the last round's figures describe the returned model
    resid = np.abs(np.asarray(model(X)) - H)
    assert rep.max_residual == pytest.approx(resid.max(), rel=1e-9, abs=1e-15)
    assert rep.rounds[-1].n_above == int(np.sum(resid > rep.tol))
    assert float(model.residual) == pytest.approx(resid.max() / np.abs(H).max(), rel=1e-9)
    return resid


@pytest.mark.slow
def test_meets_tol_with_fewer_centres():
    tol = 2e-2 * OFFSET
    model, rep = greedy_fit(C, tol=tol)
    resid = _check_report(rep, model)
    assert rep.converged and "every residual <= tol" in rep.reason
    assert resid.max() <= tol and rep.max_residual <= tol and rep.rounds[-1].n_above == 0
    assert len(rep.rounds) >= 2 and rep.rounds[0].n_above > 0
    assert rep.n_centres < 0.5 * N
    # the surface is there: f = 0 on the sphere (up to tol), negative inside, positive outside
    q = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 2.0]])
    assert float(model(q[:1])[0]) < 0 < float(model(q[1:])[0])
    text = str(rep)
    assert text.startswith("greedy fit converged") and f"{rep.n_centres:,} centres" in text
    assert len(text.splitlines()) == 2 + len(rep.rounds)


def test_all_points_gives_the_dense_fit():
    # a tolerance no subset can meet: the centres grow to every point, and the model is the
    # interpolant through all of them
    model, rep = greedy_fit(C, tol=1e-9 * OFFSET, initial=N // 4, batch=N, max_centres=N)
    _check_report(rep, model)
    assert [r.centres for r in rep.rounds] == [N // 4, N]
    assert np.array_equal(rep.centre_indices, np.arange(N))
    dense = jaxrbf.fit(C, solver="lu")
    q = np.random.default_rng(3).uniform(-1.3, 1.3, (400, 3))
    ref = np.asarray(dense(q))
    np.testing.assert_allclose(np.asarray(model(q)), ref, atol=1e-6 * np.abs(ref).max())
    if not rep.converged:  # CG's residual may sit just above 1e-9 d: then says why
        assert "all centres already" in rep.reason


def test_stops_early_without_raising(capsys):
    tol = 1e-2 * OFFSET
    model, rep = greedy_fit(C, tol=tol, max_rounds=1, verbose=True)
    assert not rep.converged and len(rep.rounds) == 1 and "max_rounds = 1" in rep.reason
    assert rep.max_residual > tol and rep.rounds[0].n_above > 0
    assert str(rep).startswith("greedy fit did NOT converge")
    err = capsys.readouterr().err
    assert "greedy round 1:" in err and "did NOT converge" in err and "greedy round 2" not in err

    first = rep.n_centres
    model, rep = greedy_fit(C, tol=tol, batch=10, max_centres=first + 10)
    _check_report(rep, model)
    assert not rep.converged and "max_centres = " in rep.reason
    assert [r.centres for r in rep.rounds] == [first, first + 10]


def test_spread_picks_the_worst_of_each_cell():
    x = np.random.default_rng(0).random((400, 3))
    score = np.random.default_rng(1).random(400)
    idx = np.flatnonzero(score > 0.3)
    picked = _spread(x, idx, 20, score)
    assert len(picked) == len(set(picked.tolist())) == 20 and set(picked) <= set(idx)
    assert int(idx[np.argmax(score[idx])]) in picked  # the worst of all is always among them
    assert np.array_equal(_spread(x, idx, 10**6, score), np.sort(idx))  # few: all of them


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"tol": 0.0}, "`tol` must be a positive, finite distance"),
        ({"tol": -1e-3}, "`tol` must be a positive, finite distance"),
        ({"tol": float("nan")}, "`tol` must be a positive, finite distance"),
        ({"tol": float("inf")}, "`tol` must be a positive, finite distance"),
        ({"tol": "small"}, "`tol` must be a positive number"),
        ({"batch": 0}, r"`batch` must be a positive integer \(>= 1\), got 0"),
        ({"batch": 2.5}, "`batch` must be a positive integer, got 2.5"),
        ({"max_rounds": 0}, "`max_rounds` must be a positive integer"),
        ({"initial": 100, "max_centres": 99}, "`max_centres` = 99 is smaller than the initial"),
        ({"initial": 3}, "`initial` = 3 centres cannot determine the 4 polynomial terms"),
        ({"initial": 10_000}, "`initial` = 10,000 is more than the 900 points"),
        ({"initial": np.array([0, 1, 2, 900])}, r"indices outside \[0, 900\)"),
        ({"initial": np.array([0, 1, 2, 3, 3, 5])}, "`initial` repeats 1 indices"),
        ({"initial": np.array([0.5, 1.5])}, "1-D array of point indices"),
        ({"initial": np.arange(4)}, "`initial` holds 4 indices, too few for the 4 polynomial"),
        ({"initial": np.arange(300)}, "every point in `initial` has value 0"),
        ({"max_centres": 4, "initial": 3}, "`initial` = 3 centres cannot"),
        ({"solver": "qr"}, "unknown solver 'qr'"),
        ({"degree": 2}, "`degree` must be -1"),
        ({"seed": 1.5}, "`seed` must be an integer"),
    ],
)
def test_validation(kwargs, match):
    with pytest.raises(InputError, match=match):
        greedy_fit(X, H, **kwargs)


def test_validation_of_the_data():
    with pytest.raises(InputError, match="`values` is missing"):
        greedy_fit(X)
    with pytest.raises(InputError, match="not both"):
        greedy_fit(C, H)
    with pytest.raises(InputError, match=r"`values` must have shape \(900,\)"):
        greedy_fit(X, H[:-1])
    with pytest.raises(InputError, match="every value is 0"):
        greedy_fit(X, np.zeros(N))
    with pytest.raises(InputError, match="1 duplicate points .first: row 900"):
        greedy_fit(np.vstack([X, X[:1]]), np.append(H, 1.0))
    with pytest.raises(InputError, match="`max_centres` = 4 cannot determine the 4 polynomial"):
        greedy_fit(X, H, initial=np.arange(N - 5, N), max_centres=4)
