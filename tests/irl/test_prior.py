"""Priors over the reward weights (pipeline/irl/prior.py): the log densities by formula, the
box, validation, samples and the mean within the box against numerical integration."""

import math

import numpy as np
import pytest
from scipy.integrate import quad
from scipy.stats import truncnorm

from pipeline.core.params import ParameterError
from pipeline.irl.prior import BoxConfig, Prior, PriorConfig
from tests.irl.conftest import BOX, D, central_difference


def test_prior_log_pdf_formulas_and_box():
    mu, w1, w2 = np.array([-0.2, -0.5, 0, -1]), np.full(D, -0.3), np.array([-0.9, -0.1, -0.5, 0])
    g, lap, uni = (Prior(k, 0.4, *BOX, mean=mu) for k in ("gaussian", "laplace", "uniform"))
    assert g.log_pdf(w1) - g.log_pdf(w2) == pytest.approx(
        -(np.sum((w1 - mu) ** 2) - np.sum((w2 - mu) ** 2)) / (2 * 0.4**2))
    assert lap.log_pdf(w1) - lap.log_pdf(w2) == pytest.approx(
        -(np.sum(np.abs(w1 - mu)) - np.sum(np.abs(w2 - mu))) / 0.4)
    assert uni.log_pdf(w1) == uni.log_pdf(w2) == 0.0
    np.testing.assert_array_equal(lap.grad_log_pdf(mu), np.zeros(D))  # sign(0) = 0
    for p in (g, lap, uni):
        assert p.log_pdf(np.array([-0.5, -0.5, 0.01, -0.5])) == -np.inf
        assert p.log_pdf(np.array([-1.01, -0.5, -0.5, -0.5])) == -np.inf
        assert np.isfinite(p.log_pdf(BOX[0])) and np.isfinite(p.log_pdf(BOX[1]))  # closed box


def test_prior_default_mean_is_zero_clipped_into_box():
    prior = Prior("gaussian", 1.0, np.array([-1.0, 0.5, -2.0]), np.array([0.0, 1.0, -1.0]))
    np.testing.assert_array_equal(prior.mean, [0.0, 0.5, -1.0])


@pytest.mark.parametrize("kwargs, message", [
    (dict(kind="cauchy"), "kind"),
    (dict(scale=0.0), "scale"),
    (dict(lower=np.zeros(2), upper=np.zeros(2)), "lower < upper"),
    (dict(lower=-np.ones(3)), "shape"),
    (dict(mean=np.zeros(3)), "mean"),
    (dict(lower=np.array([-np.inf, -1.0])), "finite"),
])
def test_prior_validation(kwargs, message):
    args = dict(kind="gaussian", scale=1.0, lower=-np.ones(2), upper=np.zeros(2)) | kwargs
    with pytest.raises(ValueError, match=message):
        Prior(**args)


# Means inside the box, on its edge and outside it (deep in the tail for one dimension).
TEST_MEANS = np.array([-0.3, 0.0, 0.5, -4.0])


@pytest.mark.parametrize("kind", ["gaussian", "laplace", "uniform"])
def test_prior_samples_in_box_with_box_mean(kind):
    prior = Prior(kind, 0.3, *BOX, mean=TEST_MEANS)
    rng = np.random.default_rng(1)
    single = prior.sample(rng)
    assert single.shape == (D,) and prior.in_box(single)
    draws = prior.sample(rng, size=20_000)
    assert np.all((draws >= BOX[0]) & (draws <= BOX[1]))
    se = draws.std(axis=0) / np.sqrt(len(draws))
    assert np.all(np.abs(draws.mean(axis=0) - prior.box_mean()) < 4 * se + 1e-12)
    # box_mean against direct numerical integration of the truncated density
    for j in range(D):
        def density(x, j=j):
            return math.exp(prior.log_pdf(np.where(np.arange(D) == j, x, prior.box_mean())))
        kink = [TEST_MEANS[j]] if -1 < TEST_MEANS[j] < 0 else None
        mass = quad(density, -1, 0, points=kink)[0]
        first = quad(lambda x: x * density(x), -1, 0, points=kink)[0]
        assert prior.box_mean()[j] == pytest.approx(first / mass, abs=1e-7)


def test_box_means_uniform_and_truncnorm():
    lower, upper = np.array([-1.0, -3.0]), np.array([0.0, 2.0])
    np.testing.assert_allclose(Prior("uniform", 1.0, lower, upper).box_mean(), [-0.5, -0.5])
    mu, sigma = np.array([0.3, -1.0]), 0.8
    expected = [truncnorm.mean((lo - m) / sigma, (hi - m) / sigma, loc=m, scale=sigma)
                for lo, hi, m in zip(lower, upper, mu, strict=True)]
    np.testing.assert_allclose(Prior("gaussian", sigma, lower, upper, mu).box_mean(), expected)


@pytest.mark.parametrize("kind", ["gaussian", "laplace", "uniform"])
def test_prior_gradient_and_hessian_are_the_log_densitys_derivatives(kind):
    """Central differences of log_pdf and grad_log_pdf inside the box, away from the Laplace
    peak (its kink): the gradient, and the diagonal Hessian (-1/σ² Gaussian, else 0)."""
    prior = Prior(kind, 0.3, *BOX, mean=np.array([-0.2, -0.5, 0.0, -1.0]))
    w = np.array([-0.6, -0.1, -0.35, -0.8])
    np.testing.assert_allclose(prior.grad_log_pdf(w), central_difference(prior.log_pdf, w),
                               rtol=1e-7, atol=1e-7)
    hessian = np.array([central_difference(lambda v, j=j: prior.grad_log_pdf(v)[j], w)[j]
                        for j in range(D)])
    np.testing.assert_allclose(prior.hess_log_pdf(w), hessian, rtol=1e-6, atol=1e-6)
    if kind == "gaussian":
        np.testing.assert_allclose(prior.hess_log_pdf(w), -1 / 0.3**2)


def test_check_start_wants_one_weight_per_feature_in_the_box():
    prior = Prior("uniform", 1.0, *BOX)
    np.testing.assert_array_equal(prior.check_start(BOX[1]), np.zeros(D))  # the face counts
    for w0 in ([-0.5], np.full(D + 1, -0.5), np.full((1, D), -0.5), np.full(D, 0.1)):
        with pytest.raises(ValueError, match="w0 must have shape"):
            prior.check_start(w0)


def test_box_config_allows_a_prior_mean_on_the_box_face():
    """The usual Gaussian centre, no cost (0), is the upper face of the default box."""
    prior = BoxConfig(prior=PriorConfig("gaussian", 0.5, mean=[0.0])).make_prior(3)
    np.testing.assert_array_equal(prior.mean, np.zeros(3))
    assert BoxConfig(prior=PriorConfig("laplace", 0.5, mean=[-1.0, 0.0])).make_prior(2).kind \
        == "laplace"
    with pytest.raises(ParameterError, match="prior.mean"):
        BoxConfig(prior=PriorConfig("gaussian", 0.5, mean=[0.1])).make_prior(3)


def test_box_config_takes_one_number_or_one_per_feature():
    np.testing.assert_array_equal(BoxConfig(lower=[-2.0, -1.0]).make_prior(2).lower,
                                  [-2.0, -1.0])
    with pytest.raises(ParameterError, match="lower"):
        BoxConfig(lower=[-2.0, -1.0, -1.0]).make_prior(2)
    with pytest.raises(ParameterError, match="upper"):
        BoxConfig(upper=[0.0, 0.0]).make_prior(3)


def test_weights_printed_at_a_bound_or_the_middle_are_at_the_box():
    """The run summary names the weights at the box (Prior.at_box) as it prints them, to 3
    decimals: the MAP's Newton steps stop a little short of a bound, and social -0.0003
    (printed 0.000, the upper bound) and crossing -0.49987 (printed -0.500, the middle),
    learned from a walker's paths, were not named."""
    box = BoxConfig().make_prior(5)  # [-1, 0]^5
    at = box.at_box([-0.804, -0.0003071, 0.0, -0.511, -0.4998713])
    assert at["upper bound"].tolist() == [False, True, True, False, False]
    assert at["middle"].tolist() == [False, False, False, False, True]
    assert not at["lower bound"].any()
    # learned weights: printed away from the box's corners and middle
    assert not any(m.any() for m in box.at_box([-0.872, -0.209, -0.554, -0.39, -0.45]).values())
    assert not any(m.any() for m in box.at_box([np.nan] * 5).values())
    # relative to the box's width: 0.0009 from a bound of a box 2 wide is at it (0.00045 in
    # the unit box), 0.0011 is not
    wide = Prior("uniform", 1.0, np.array([-2.0, -2.0]), np.array([0.0, 0.0]))
    assert wide.at_box([-1.9991, -1.9989])["lower bound"].tolist() == [True, False]
