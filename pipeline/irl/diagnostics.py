"""Convergence diagnostics of MCMC chains: rank-normalised split R-hat and bulk effective
sample size (ESS) of Vehtari, Gelman, Simpson, Carpenter and Bürkner (2021), "Rank-normalization,
folding, and localization: an improved R-hat for assessing convergence of MCMC", Bayesian
Analysis 16(2).

The arithmetic follows ArviZ (`az.rhat`, `az.ess(method="bulk")`, 0.23) step by step, in the
same order, so both give the same numbers to the last bits; tests/irl/test_diagnostics.py
holds ArviZ's values for reference draws.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from scipy import fft, special

MIN_DRAWS = 4  # per chain; fewer give no diagnostics (NaN), as in ArviZ
BLOM_OFFSET = 3 / 8  # the fractional offset of the rank normalisation (Blom 1958)
# The chains agree when every weight's split R-hat is at most this and its bulk ESS at least
# AGREED_ESS (Vehtari et al. 2021 ask R-hat < 1.01 of long runs; 4 short chains reach 1.05)
AGREED_RHAT = 1.05
AGREED_ESS = 100


def chains_agree(rhat: npt.ArrayLike, ess: npt.ArrayLike) -> bool:
    """Every R-hat at most AGREED_RHAT and every ESS at least AGREED_ESS, NaN (a constant
    parameter, one chain) not counted."""
    r, e = np.asarray(rhat, float), np.asarray(ess, float)
    return bool((r[np.isfinite(r)] <= AGREED_RHAT).all()
                and (e[np.isfinite(e)] >= AGREED_ESS).all())


def convergence(draws: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """R-hat and bulk ESS per parameter (each (d,)) of draws (chains, samples, d). R-hat
    needs two chains or more (NaN otherwise); constant draws give R-hat NaN."""
    draws = np.asarray(draws, dtype=float)
    if draws.ndim != 3:
        raise ValueError(f"draws must be (chains, samples, d), got shape {draws.shape}")
    d = draws.shape[2]
    with np.errstate(divide="ignore", invalid="ignore"):  # constant chains: 0/0
        rhat = np.array([split_rhat(draws[:, :, j]) for j in range(d)], dtype=float)
        ess = np.array([bulk_ess(draws[:, :, j]) for j in range(d)], dtype=float)
    return rhat, ess


def split_rhat(chains: np.ndarray) -> float:
    """Rank-normalised split R-hat of one parameter's draws (chains, samples): the larger of
    the bulk R-hat (of the rank-normalised split chains) and the tail R-hat (of the same
    after folding around the median)."""
    n_chains, n_draws = chains.shape
    if n_chains < 2 or n_draws < MIN_DRAWS or np.isnan(chains).any():
        return float("nan")
    split = split_chains(chains)
    bulk = _rhat(rank_normalise(split))
    tail = _rhat(rank_normalise(np.abs(split - np.median(split))))
    return float(tail if tail > bulk else bulk)  # ArviZ's max(bulk, tail): a NaN bulk stays


def bulk_ess(chains: np.ndarray) -> float:
    """Bulk effective sample size of one parameter's draws (chains, samples): the ESS of
    the rank-normalised split chains."""
    n_draws = chains.shape[1]
    if n_draws < MIN_DRAWS or np.isnan(chains).any():
        return float("nan")
    return _ess(rank_normalise(split_chains(chains)))


def split_chains(chains: np.ndarray) -> np.ndarray:
    """Each chain cut into its first and last half (the middle draw of an odd length
    dropped), stacked: (2 chains, samples // 2)."""
    half = chains.shape[1] // 2
    return np.vstack((chains[:, :half], chains[:, -half:]))


def rank_normalise(x: np.ndarray) -> np.ndarray:
    """Normal scores of the pooled ranks (ties averaged): Phi^-1((r - 3/8) / (S - 3/4 + 1))."""
    from scipy.stats import rankdata  # here: scipy.stats takes ~0.3 s to import

    ranks = rankdata(x, method="average")
    c = BLOM_OFFSET
    return np.asarray(special.ndtri((ranks - c) / (ranks.size - 2 * c + 1))).reshape(x.shape)


def autocovariance(x: np.ndarray) -> np.ndarray:
    """Autocovariance of each row of x (chains, samples) at every lag, by FFT (zero-padded to
    a fast length >= twice the samples), normalised by the number of samples."""
    n = x.shape[1]
    centred = x - x.mean(axis=1, keepdims=True)
    m = fft.next_fast_len(2 * n, real=True)
    spectrum = np.fft.rfft(centred, n=m, axis=1)
    spectrum *= np.conjugate(spectrum)
    cov = np.fft.irfft(spectrum, n=m, axis=1)[:, :n]
    cov /= n
    return cov


def _rhat(x: np.ndarray) -> float:
    """Potential scale reduction of x (chains, samples): sqrt(((n-1)/n W + B/n) / W)."""
    n = x.shape[1]
    between = n * np.var(np.mean(x, axis=1), ddof=1)
    within = np.mean(np.var(x, axis=1, ddof=1))
    return float(np.sqrt((between / within + n - 1) / n))


def _ess(x: np.ndarray) -> float:
    """Effective sample size of x (chains, samples): S / tau with the integrated
    autocorrelation tau of the combined chains, its sum truncated by Geyer's initial positive
    sequence and made monotone (Geyer's initial monotone sequence)."""
    if np.max(x) - np.min(x) < np.finfo(float).resolution:
        return float(x.size)  # constant draws
    n_chains, n = x.shape
    acov = autocovariance(x)
    mean_var = np.mean(acov[:, 0]) * n / (n - 1.0)
    var_plus = mean_var * (n - 1.0) / n
    if n_chains > 1:
        var_plus += np.var(x.mean(axis=1), ddof=1)

    def rho_at(lag: int) -> float:  # combined-chain autocorrelation at lag
        return float(1.0 - (mean_var - np.mean(acov[:, lag])) / var_plus)

    rho = np.zeros(n)
    rho_even, rho_odd = 1.0, rho_at(1)
    rho[0], rho[1] = rho_even, rho_odd
    # Initial positive sequence: pairs of lags while the pair sum is positive.
    t = 1
    while t < n - 3 and rho_even + rho_odd > 0.0:
        rho_even, rho_odd = rho_at(t + 1), rho_at(t + 2)
        if rho_even + rho_odd >= 0:
            rho[t + 1], rho[t + 2] = rho_even, rho_odd
        t += 2
    max_t = t - 2
    if rho_even > 0:  # the last even lag still adds information
        rho[max_t + 1] = rho_even
    # Initial monotone sequence: no pair sum may exceed the one before it.
    t = 1
    while t <= max_t - 2:
        if rho[t + 1] + rho[t + 2] > rho[t - 1] + rho[t]:
            rho[t + 1] = (rho[t - 1] + rho[t]) / 2.0
            rho[t + 2] = rho[t + 1]
        t += 2
    size = n_chains * n
    tau = -1.0 + 2.0 * np.sum(rho[: max_t + 1]) + np.sum(rho[max_t + 1 : max_t + 2])
    tau = max(tau, 1 / np.log10(size))  # at most S log10(S) (antithetic chains)
    return float("nan") if np.isnan(rho).any() else float(size / tau)
