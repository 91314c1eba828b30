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


def _ar1(rng, n, phi, size):
    """``size`` AR(1) series of length ``n``, unit innovations, started stationary."""
    e = rng.normal(size=(size, n))
    u = np.empty_like(e)
    u[:, 0] = e[:, 0] / np.sqrt(1 - phi ** 2)
    for k in range(1, n):
        u[:, k] = phi * u[:, k - 1] + e[:, k]
    return u


def test_hac_standard_errors_cover_the_truth_under_residuals_correlated_in_time():
    """A line fitted to a slow regressor with AR(1) residuals (phi 0.5): iid standard errors are
    too small (the residuals' variance counts each sample as new), Newey-West's sandwich covers
    the truth at about the nominal rate over 300 replications."""
    rng = np.random.default_rng(5)
    n, reps = 400, 300
    x = np.sin(2 * np.pi * 2 * np.arange(n) / n)
    U = 0.1 * _ar1(rng, n, 0.5, reps)
    hits = {"iid": np.zeros(2), "hac": np.zeros(2)}
    for u in U:
        y = 2.0 + 3.0 * x + u
        for cov in hits:
            res = least_squares_fit(_line(x, y), [1.0, 1.0], ["a", "b"], covariance=cov)
            hits[cov] += np.abs(res.x - [2.0, 3.0]) <= 2 * res.stderr
    rate = {k: v / reps for k, v in hits.items()}
    assert np.all(rate["hac"] >= 0.88) and np.all(rate["hac"] <= 0.99), rate
    assert np.all(rate["iid"] <= 0.82), rate


def test_input_noise_standard_errors_cover_the_truth_with_errors_in_the_inputs():
    """Errors in the variables: y = b (h * u) + c + e, a low-pass ``h`` of the true input u;
    the fit sees u + w (white input noise, sigma 0.3) and puts its response b (h * w) in the
    residuals, where it is small against e yet moves b. ``covariance="inputs"`` with draws of
    that response covers the truth at the nominal rate; iid standard errors do not."""
    rng = np.random.default_rng(6)
    n, reps, s_u, s_e = 300, 200, 0.3, 0.05
    t = np.arange(n) * 0.01
    h = np.exp(-np.arange(40) / 10.0)
    h /= h.sum()
    low = lambda v: np.convolve(v, h)[:n]  # noqa: E731  (causal: the response to an input)
    u = np.sin(2 * np.pi * 1.5 * t) + 0.5 * np.sin(2 * np.pi * 0.4 * t)
    truth = np.array([2.0, 0.3])
    hits = {"iid": np.zeros(2), "inputs": np.zeros(2)}
    for _ in range(reps):
        um = u + s_u * rng.normal(size=n)
        y = truth[0] * low(u) + truth[1] + s_e * rng.normal(size=n)
        X = np.stack([low(um), np.ones(n)], axis=1)
        W = np.stack([low(w) for w in s_u * np.random.default_rng(0).normal(size=(40, n))])

        for cov in hits:
            res = least_squares_fit(lambda th: (X @ th - y, X), [1.0, 0.0], ["b", "c"], covariance=cov,
                                    input_draws=lambda th: th[0] * W)
            hits[cov] += np.abs(res.x - truth) <= 2 * res.stderr
    rate = {k: v / reps for k, v in hits.items()}
    assert np.all(rate["inputs"] >= 0.88) and np.all(rate["inputs"] <= 0.995), rate
    assert rate["iid"][0] <= 0.8, rate


def test_an_unknown_covariance_is_refused_by_name():
    with pytest.raises(ValueError, match=r"covariance must be 'iid', 'hac' or 'inputs', got 'sandwich'"):
        least_squares_fit(_line(np.arange(5.0), np.arange(5.0)), [1.0, 1.0], ["a", "b"], covariance="sandwich")


def test_a_robust_loss_weights_the_input_draws_as_it_weights_the_residuals():
    """With a robust loss the input-noise draws pass through the loss's row weights
    (``sqrt(rho')`` at the solution) as the Jacobian does: draws that move only the outliers
    the loss has set aside leave the standard errors as they are, the same draws on inlier
    rows raise them; and the covariance is the sandwich of the weighted rows, computed here
    apart."""
    from qchain.fit.solve import robust_weights

    rng = np.random.default_rng(4)
    x = np.linspace(0, 1, 60)
    y = 2.0 + 3.0 * x + 0.01 * rng.normal(size=x.size)
    out = np.arange(0, 60, 10)
    y[out] += 1.0  # six gross outliers
    X = np.stack([np.ones_like(x), x], axis=1)
    D_out = np.zeros((40, x.size))
    D_out[:, out] = rng.normal(size=(40, 1))  # draws that shift the outliers alone, by about 1
    inl = out + 5
    D_in = np.zeros_like(D_out)
    D_in[:, inl] = 0.05 * rng.normal(size=(40, 1))  # a shift of six inliers, smaller

    def run(D):
        return least_squares_fit(_line(x, y), [1.0, 1.0], ["a", "b"], loss="cauchy", f_scale=0.02,
                                 covariance="inputs", input_draws=lambda th: D)

    none, outl, inli = run(np.zeros_like(D_out)), run(D_out), run(D_in)
    assert np.all(outl.stderr <= 1.02 * none.stderr), (outl.stderr, none.stderr)
    assert np.any(inli.stderr >= 1.05 * none.stderr), (inli.stderr, none.stderr)
    # the sandwich of the weighted rows, by hand
    w = np.sqrt(robust_weights(outl.residuals, "cauchy", 0.02))
    assert w[out].max() < 0.03 and w[inl].min() > 0.5
    sc = np.array([1.0, 1.0])
    Jw, Dw = X * sc * w[:, None], D_out * w
    U, s, Vt = np.linalg.svd(Jw, full_matrices=False)
    inv = (Vt.T / s ** 2) @ Vt
    Dperp = Dw - (Dw @ U) @ U.T
    sm2 = max(2 * outl.cost - np.mean(np.sum(Dperp ** 2, axis=1)), 0.0) / (x.size - 2)
    G = Dw @ Jw
    np.testing.assert_allclose(outl.covariance, sm2 * inv + inv @ (G.T @ G / 40) @ inv, rtol=1e-8)
    # (the draws left unweighted would give another covariance: the test tells them apart)
    Dperp0 = D_out - (D_out @ U) @ U.T
    sm20 = max(2 * outl.cost - np.mean(np.sum(Dperp0 ** 2, axis=1)), 0.0) / (x.size - 2)
    G0 = D_out @ Jw
    other = sm20 * inv + inv @ (G0.T @ G0 / 40) @ inv
    assert np.abs(np.diag(other) / np.diag(outl.covariance) - 1).max() > 0.1
