"""MCMC convergence diagnostics (pipeline.irl.diagnostics): ArviZ's own numbers for fixed
draws, and the properties R-hat and the bulk ESS must have."""

import numpy as np
import pytest

from pipeline.irl.diagnostics import (
    AGREED_ESS,
    AGREED_RHAT,
    autocovariance,
    chains_agree,
    convergence,
)


def ar1(rho: float, shape: tuple[int, int, int], rng: np.random.Generator) -> np.ndarray:
    """Stationary Gaussian AR(1) chains (chains, samples, d) with unit variance."""
    chains, n, d = shape
    x = np.empty(shape)
    x[:, 0] = rng.normal(size=(chains, d))
    noise = rng.normal(size=shape) * np.sqrt(1 - rho**2)
    for t in range(1, n):
        x[:, t] = rho * x[:, t - 1] + noise[:, t]
    return x


def reference_draws() -> dict[str, np.ndarray]:
    """Draws (chains, samples, d) covering the branches: iid, autocorrelated, stuck chains,
    an odd length (split drops the middle draw), ties, heavy tails (the folded R-hat decides),
    one chain, a constant parameter, the fewest draws."""
    rng = np.random.default_rng(2021)
    stuck = rng.normal(size=(4, 200, 2)) + np.array([0.0, 0.0, 2.0, 2.0])[:, None, None]
    constant = rng.normal(size=(3, 50, 2))
    constant[:, :, 1] = 0.25
    cauchy = rng.standard_cauchy(size=(4, 300, 1))
    cauchy[0] *= 5.0  # one chain with wider tails: same centre, different spread
    return {
        "iid": rng.normal(size=(4, 500, 2)),
        "ar1": ar1(0.8, (3, 400, 2), rng),
        "stuck": stuck,
        "odd_length": rng.normal(size=(2, 101, 1)),
        "ties": rng.integers(0, 3, size=(4, 60, 1)).astype(float),
        "heavy_tails": cauchy,
        "one_chain": ar1(0.5, (1, 300, 1), rng),
        "constant": constant,
        "four_draws": rng.normal(size=(2, 4, 1)),
    }


# az.rhat and az.ess(method="bulk") of ArviZ 0.23.4 (scipy 1.17.1, numpy 2.4.6) on
# reference_draws(), made from the repository root with
#   pip install arviz==0.23.4
#   python -c "from tests.irl.test_diagnostics import reference_draws; import arviz as az
#   for k, x in reference_draws().items():
#       ds = az.convert_to_dataset(x)
#       print(k, az.rhat(ds)['x'].values.tolist(), az.ess(ds, method='bulk')['x'].values.tolist())"
ARVIZ = {
    "iid": ([1.00225234870365, 1.0001276942736932], [1945.2555574468054, 2033.7175058088635]),
    "ar1": ([1.0077519643713917, 1.01560762764428], [128.08451401978547, 150.18560737563791]),
    "stuck": ([1.4469408252301057, 1.4404254137552535], [8.214233543209097, 8.479082426785746]),
    "odd_length": ([1.0098899157131382], [215.4645830108558]),
    "ties": ([1.0144185099947227], [256.3160191448846]),
    "heavy_tails": ([1.1145849100981613], [1178.1573888071487]),
    "one_chain": ([float("nan")], [75.88700469526928]),
    "constant": ([0.9982304734143673, float("nan")], [110.26613717021571, 150.0]),
    "four_draws": ([0.9012144386980897], [7.224719895935548]),
}


@pytest.mark.parametrize("name", list(ARVIZ))
def test_the_numbers_are_arvizs(name):
    rhat, ess = convergence(reference_draws()[name])
    want_rhat, want_ess = ARVIZ[name]
    np.testing.assert_allclose(rhat, want_rhat, rtol=1e-12)  # NaN where ArviZ has NaN
    np.testing.assert_allclose(ess, want_ess, rtol=1e-12)


def test_iid_chains_have_rhat_one_and_ess_the_number_of_draws():
    rng = np.random.default_rng(0)
    rhat, ess = convergence(rng.normal(size=(4, 1000, 10)))
    assert np.all(np.abs(rhat - 1) < 0.01)
    assert np.mean(ess) == pytest.approx(4000, rel=0.05)


def test_chains_stuck_at_different_means_have_rhat_far_above_one():
    rng = np.random.default_rng(1)
    means = np.array([0.0, 0.0, 3.0, 3.0])[:, None, None]
    rhat, ess = convergence(rng.normal(size=(4, 500, 3)) + means)
    assert np.all(rhat > 1.5)
    assert np.all(ess < 20)  # 4 x 500 draws worth a handful: the chains disagree


def test_ar1_chains_have_the_theoretical_ess():
    rho, shape = 0.9, (4, 5000, 8)
    rhat, ess = convergence(ar1(rho, shape, np.random.default_rng(2)))
    theory = shape[0] * shape[1] * (1 - rho) / (1 + rho)  # S (1 - rho) / (1 + rho)
    assert np.mean(ess) == pytest.approx(theory, rel=0.1)
    assert np.all(ess < 2 * theory)
    assert np.all(np.abs(rhat - 1) < 0.02)


def test_one_chain_constant_draws_and_too_few_draws():
    rng = np.random.default_rng(3)
    rhat, ess = convergence(rng.normal(size=(1, 200, 2)))
    assert np.all(np.isnan(rhat)) and np.all(ess > 50)  # ESS needs one chain only
    rhat, ess = convergence(np.full((4, 100, 1), 2.5))
    assert np.isnan(rhat[0]) and ess[0] == 400  # constant: every draw counts
    rhat, ess = convergence(rng.normal(size=(4, 3, 1)))
    assert np.isnan(rhat[0]) and np.isnan(ess[0])


def test_autocovariance_by_fft_is_the_direct_sum():
    x = np.random.default_rng(4).normal(size=(3, 37))
    centred = x - x.mean(axis=1, keepdims=True)
    n = x.shape[1]
    direct = np.array([[c[: n - k] @ c[k:] / n for k in range(n)] for c in centred])
    np.testing.assert_allclose(autocovariance(x), direct, rtol=1e-10, atol=1e-13)


def test_draws_must_be_chains_samples_parameters():
    with pytest.raises(ValueError, match="chains, samples, d"):
        convergence(np.zeros((4, 100)))


def test_antithetic_chains_have_their_ess_capped_at_s_log10_s():
    """Draws that alternate in sign have a negative lag-1 autocorrelation: the integrated
    autocorrelation tau falls below 1/log10(S), where ArviZ caps it (ESS = S log10 S)."""
    rng = np.random.default_rng(0)
    size = np.abs(rng.normal(size=(2, 100, 1))) + 0.1
    draws = size * (-1.0) ** np.arange(100)[None, :, None]
    _, ess = convergence(draws)
    assert ess[0] == pytest.approx(200 * np.log10(200), rel=1e-12)


def test_chains_agree_at_the_agreed_values_and_ignore_nan():
    assert chains_agree(np.array([AGREED_RHAT, 1.0]), np.array([AGREED_ESS, 1e4]))
    assert not chains_agree(np.array([AGREED_RHAT + 1e-9]), np.array([AGREED_ESS]))
    assert not chains_agree(np.array([1.0]), np.array([AGREED_ESS - 1e-9]))
    # a constant parameter (R-hat NaN, ESS the draws) or one chain (R-hat NaN) counts as agreed
    assert chains_agree(np.array([np.nan, 1.01]), np.array([400.0, 300.0]))
    assert chains_agree(np.array([np.nan]), np.array([np.nan]))
