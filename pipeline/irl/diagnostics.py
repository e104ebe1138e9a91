"""Convergence diagnostics of MCMC chains by ArviZ, the ecosystem's standard: rank-normalised
split R-hat over the chains and bulk effective sample size (Vehtari et al. 2021)."""

from __future__ import annotations

import warnings

import numpy as np


def convergence(draws: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """R-hat and bulk ESS per parameter (each (d,)) of draws (chains, samples, d). R-hat
    needs two chains or more (NaN otherwise); constant draws give R-hat NaN."""
    with warnings.catch_warnings():  # ArviZ 0.23 announces its refactor on import
        warnings.simplefilter("ignore", FutureWarning)
        import arviz as az
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # constant chains: 0/0
        data = az.convert_to_dataset(np.asarray(draws, dtype=float))
        rhat = np.asarray(az.rhat(data)["x"].values, dtype=float).reshape(-1)
        ess = np.asarray(az.ess(data, method="bulk")["x"].values, dtype=float).reshape(-1)
    return rhat, ess
