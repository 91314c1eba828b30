"""The fit's least squares and statistics (qchain.fit.solve) on models with known answers:
linear regression's closed-form standard errors, the coverage of two standard errors over
repeated noisy experiments, parameters the data cannot tell apart, bounds, robust losses."""

from __future__ import annotations

import numpy as np
import pytest

from qchain.fit.solve import FitWarning, least_squares_fit


def _line(x, y):
    X = np.stack([np.ones_like(x), x], axis=1)
    return lambda th: (X @ th - y, X)


def test_linear_regression_standard_errors_are_the_closed_form():
    rng = np.random.default_rng(0)
    x = np.linspace(0, 1, 50)
    y = 2.0 + 3.0 * x + 0.1 * rng.normal(size=x.size)
    res = least_squares_fit(_line(x, y), [1.0, 1.0], ["a", "b"])
    X = np.stack([np.ones_like(x), x], axis=1)
    beta = np.linalg.lstsq(X, y, rcond=None)[0]
    r = y - X @ beta
    s2 = r @ r / (x.size - 2)
    cov = s2 * np.linalg.inv(X.T @ X)
    np.testing.assert_allclose(res.x, beta, rtol=1e-9)
    np.testing.assert_allclose(res.covariance, cov, rtol=1e-7)
    np.testing.assert_allclose(res.stderr, np.sqrt(np.diag(cov)), rtol=1e-7)
    assert res.sigma == pytest.approx(np.sqrt(s2), rel=1e-9)
    assert res.correlation[0, 1] == pytest.approx(cov[0, 1] / np.sqrt(cov[0, 0] * cov[1, 1]), rel=1e-7)
    assert res.success and res.unidentifiable == [] and res.njev >= 1
    assert res.table()[1].split()[0] == "a"


def test_two_standard_errors_cover_the_truth_about_95_percent_of_the_time():
    """A nonlinear model (a decaying oscillation: amplitude, rate, frequency) fitted to 200 noisy
    experiments from a wrong start: the truth within 2 standard errors in 90-99 % of them."""
    t = np.linspace(0, 2, 80)
    truth = np.array([0.05, 1.3, 2.1])

    def model(th):
        A, k, f = th
        e, s, c = np.exp(-k * t), np.sin(2 * np.pi * f * t), np.cos(2 * np.pi * f * t)
        return A * e * s, np.stack([e * s, -t * A * e * s, 2 * np.pi * t * A * e * c], axis=1)

    rng = np.random.default_rng(1)
    hits = np.zeros(3)
    for _ in range(200):
        y = model(truth)[0] + 1e-3 * rng.normal(size=t.size)
        res = least_squares_fit(lambda th: (model(th)[0] - y, model(th)[1]), [0.04, 1.0, 2.0], ["A", "k", "f"])
        hits += np.abs(res.x - truth) <= 2 * res.stderr
    assert np.all(hits >= 180) and np.all(hits <= 198), hits


def test_parameters_the_data_cannot_tell_apart_are_named():
    """y = a b x fixes the product only: a and b named, their standard errors infinite."""
    x = np.linspace(0, 1, 20)
    y = 6.0 * x + 1e-3 * np.random.default_rng(2).normal(size=x.size)
    with pytest.warns(FitWarning, match=r"the data cannot tell apart a, b: one combination"):
        res = least_squares_fit(lambda th: (th[0] * th[1] * x - y, np.stack([th[1] * x, th[0] * x], axis=1)),
                                [2.0, 2.0], ["a", "b"])
    assert res.unidentifiable == [["a", "b"]] and np.all(np.isinf(res.stderr))
    assert res.x[0] * res.x[1] == pytest.approx(6.0, rel=1e-3)
    # a third parameter the data do fix keeps its standard error
    with pytest.warns(FitWarning, match="cannot tell apart a, b"):
        res = least_squares_fit(lambda th: (th[0] * th[1] * x + th[2] - y,
                                            np.stack([th[1] * x, th[0] * x, np.ones_like(x)], axis=1)),
                                [2.0, 2.0, 0.5], ["a", "b", "c"])
    assert np.isinf(res.stderr[:2]).all() and np.isfinite(res.stderr[2]) and res.stderr[2] < 1e-2


def test_correlated_parameters_and_bounds_are_said():
    x = np.linspace(1.0, 1.01, 30)  # a and b nearly collinear over this span
    y = 2.0 + 3.0 * x + 1e-4 * np.random.default_rng(3).normal(size=x.size)
    with pytest.warns(FitWarning, match=r"a and b are correlated -(1\.0000|0\.99)"):
        least_squares_fit(_line(x, y), [1.0, 1.0], ["a", "b"])
    x = np.linspace(0, 1, 30)
    y = 2.0 + 3.0 * x
    with pytest.warns(FitWarning, match="b ended at a bound"):
        res = least_squares_fit(_line(x, y), [1.0, 1.0], ["a", "b"], lower=[-10, 0], upper=[10, 2.5])
    assert res.x[1] == pytest.approx(2.5) and res.at_bound == ["b"]


def test_a_robust_loss_shrugs_off_outliers():
    rng = np.random.default_rng(4)
    x = np.linspace(0, 1, 60)
    y = 2.0 + 3.0 * x + 0.01 * rng.normal(size=x.size)
    y[::10] += 1.0  # six gross outliers
    plain = least_squares_fit(_line(x, y), [1.0, 1.0], ["a", "b"])
    robust = least_squares_fit(_line(x, y), [1.0, 1.0], ["a", "b"], loss="soft_l1", f_scale=0.02)
    assert np.abs(robust.x - [2, 3]).max() < 0.02 < np.abs(plain.x - [2, 3]).max()


def test_bad_arguments_are_refused_by_name():
    f = _line(np.arange(5.0), np.arange(5.0))
    with pytest.raises(ValueError, match=r"b: start value 3 is outside its bounds \[0, 2\]"):
        least_squares_fit(f, [1.0, 3.0], ["a", "b"], lower=[0, 0], upper=[2, 2])
    with pytest.raises(ValueError, match=r"a: lower bound 2 must be below the upper bound 1"):
        least_squares_fit(f, [1.0, 1.0], ["a", "b"], lower=[2, 0], upper=[1, 2])
    with pytest.raises(ValueError, match="names has 1 entries for 2 parameters"):
        least_squares_fit(f, [1.0, 1.0], ["a"])
    with pytest.raises(ValueError, match="loss must be"):
        least_squares_fit(f, [1.0, 1.0], ["a", "b"], loss="l1")
    with pytest.raises(FloatingPointError, match="not finite at"):
        least_squares_fit(lambda th: (np.full(5, np.nan), np.ones((5, 2))), [1.0, 1.0], ["a", "b"])
