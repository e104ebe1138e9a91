"""Priors over reward weights (DESIGN §8): Gaussian, Laplace or uniform, truncated to a box.

Features are costs, so the box is where the weights may live (default [−1, 0]^d).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

import numpy as np
from numpy.typing import ArrayLike

from pipeline.core.params import is_number, require

PRIORS = ("gaussian", "laplace", "uniform")
# Prior.at_box: a weight this close to a bound or the middle, relative to the box's width,
# is there: half the last digit of a weight printed to 3 decimals in the unit box (the MAP's
# Newton steps stop short of a bound: social -0.0003 and crossing -0.49987, printed 0.000 and
# -0.500, were not named at 1e-6)
AT_BOX_TOLERANCE = 5e-4


@dataclass
class PriorConfig:
    kind: str = "uniform"  # uniform (on the box) | gaussian | laplace
    scale: float = 0.5  # σ (gaussian) or b (laplace)
    # One number, or one per feature; null: 0 clipped into the box.
    mean: Optional[list[float]] = None

    def __post_init__(self) -> None:
        require(self.kind in PRIORS, "kind", self.kind, " or ".join(repr(k) for k in PRIORS))
        # beyond the largest weight the prior is flat on any box: the uniform prior, whose
        # draws and means a huge σ or b would lose to round-off; below the smallest it is a
        # point (1/σ² overflowed at 1e-160)
        require(is_number(self.scale) and SMALLEST_SCALE <= self.scale <= LARGEST_WEIGHT,
                "scale", self.scale, f"a number >= {SMALLEST_SCALE:g} and <= "
                f"{LARGEST_WEIGHT:g} (larger: kind=uniform; smaller: birl=fixed)")


# Weights beyond this size leave β·w out of what the learned β (birl.beta_min ..
# birl.beta_max) can scale back: with a box of ±1e12 the weights never left their start.
LARGEST_WEIGHT = 1e6
# A prior narrower than this pins the weights to its centre as birl=fixed would, and its
# 1/σ² leaves float64 far below (ZeroDivisionError at σ = 1e-300).
SMALLEST_SCALE = 1e-6


@dataclass
class BoxConfig:
    """The weight box and prior shared by every IRL method; one number applies to every
    feature, or give one per feature."""
    prior: PriorConfig = field(default_factory=PriorConfig)
    # the weight box, one number for every feature or one per feature (costs weigh < 0):
    lower: list[float] = field(default_factory=lambda: [-1.0])  # the box's lower corner
    upper: list[float] = field(default_factory=lambda: [0.0])  # the box's upper corner

    def make_prior(self, dim: int) -> Prior:
        """The prior on the box for `dim` features; ParameterError naming a wrong entry."""
        lower, upper = broadcast(self.lower, dim, "lower"), broadcast(self.upper, dim, "upper")
        require(bool(np.all(lower < upper)), "lower", list(self.lower),
                f"below upper ({list(self.upper)}) in every entry")
        for name, bound in (("lower", lower), ("upper", upper)):
            require(bool(np.all(np.abs(bound) <= LARGEST_WEIGHT)), name, list(getattr(self, name)),
                    f"numbers within ±{LARGEST_WEIGHT:g}")
        mean = None if self.prior.mean is None else broadcast(self.prior.mean, dim, "prior.mean")
        # a centre far outside the box makes every weight in it improbable to round-off
        require(mean is None or bool(np.all((mean >= lower) & (mean <= upper))), "prior.mean",
                self.prior.mean, "within the box [lower, upper] in every entry")
        return Prior(self.prior.kind, self.prior.scale, lower, upper, mean)


def broadcast(values: list[float], dim: int, name: str) -> np.ndarray:
    """A config list of one number (for every feature) or `dim` numbers, as a (dim,) array."""
    arr = np.asarray(list(values), dtype=float).reshape(-1)
    require(len(arr) in (1, dim) and bool(np.all(np.isfinite(arr))), name, list(values),
            f"one finite number, or {dim} (one per feature)")
    return np.broadcast_to(arr, (dim,)).copy()


def _truncated_exponential_mean(length: np.ndarray, b: float) -> np.ndarray:
    """Mean of the density ∝ exp(−z/b) on [0, L]: b − L / (exp(L/b) − 1), and 0 if L = 0;
    per entry of `length` (d,)."""
    x = np.where(length > 0, length / b, 1.0)
    return np.where(length > 0, b - length * np.exp(-x) / -np.expm1(-x), 0.0)


@dataclass(frozen=True, eq=False)
class Prior:
    kind: str  # 'gaussian' | 'laplace' | 'uniform'
    scale: float  # σ or b (ignored for uniform); > 0
    lower: np.ndarray  # (d,)
    upper: np.ndarray  # (d,)
    mean: np.ndarray | None = None  # default: zeros(d) clipped into the box

    def __post_init__(self) -> None:
        if self.kind not in PRIORS:
            raise ValueError(f"prior kind must be one of {PRIORS}, got {self.kind!r}")
        if not self.scale > 0:
            raise ValueError(f"prior scale must be > 0, got {self.scale!r}")
        lower = np.atleast_1d(np.asarray(self.lower, dtype=float))
        upper = np.atleast_1d(np.asarray(self.upper, dtype=float))
        if lower.ndim != 1 or lower.shape != upper.shape:
            raise ValueError(f"prior bounds need equal 1-D shape, got {lower.shape}, {upper.shape}")
        if not np.all(np.isfinite(lower) & np.isfinite(upper) & (lower < upper)):
            raise ValueError(f"prior needs finite lower < upper in every dimension, "
                             f"got {lower} and {upper}")
        mean = np.clip(0.0, lower, upper) if self.mean is None else np.asarray(self.mean, float)
        if mean.shape != lower.shape:
            raise ValueError(f"prior mean must have shape {lower.shape}, got {mean.shape}")
        for name, value in (("lower", lower), ("upper", upper), ("mean", mean)):
            object.__setattr__(self, name, value)

    @property
    def dim(self) -> int:
        return len(self.lower)

    def in_box(self, w: np.ndarray) -> bool:
        return bool(np.all((w >= self.lower) & (w <= self.upper)))

    def at_box(self, w: ArrayLike, tolerance: float = AT_BOX_TOLERANCE) -> dict[str, np.ndarray]:
        """Which entries of w (d,) lie at the box's lower bound, its upper bound or its middle:
        boolean masks (d,) under those three keys, each within `tolerance` × the box's width
        (NaN: none of them)."""
        w = np.asarray(w, dtype=float)

        def near(target: np.ndarray) -> np.ndarray:
            return np.abs(w - target) <= tolerance * (self.upper - self.lower)

        return {"lower bound": near(self.lower), "upper bound": near(self.upper),
                "middle": near((self.lower + self.upper) / 2)}

    def check_start(self, w0: ArrayLike) -> np.ndarray:
        """w0 as a new float array (d,), if it lies in the box; else a ValueError."""
        w = np.array(w0, dtype=float)
        if w.shape != (self.dim,) or not self.in_box(w):
            raise ValueError(f"w0 must have shape ({self.dim},) and lie in the prior box, got {w}")
        return w

    def log_pdf(self, w: ArrayLike) -> float:
        """Log density up to a constant at w (d,); −inf outside the box."""
        w = np.asarray(w, dtype=float)
        if not self.in_box(w):
            return -np.inf
        if self.kind == "gaussian":
            return float(-np.sum((w - self.mean) ** 2) / (2 * self.scale**2))
        if self.kind == "laplace":
            return float(-np.sum(np.abs(w - self.mean)) / self.scale)
        return 0.0

    def grad_log_pdf(self, w: ArrayLike) -> np.ndarray:
        w = np.asarray(w, dtype=float)
        if self.kind == "gaussian":
            return -(w - self.mean) / self.scale**2
        if self.kind == "laplace":
            return -np.sign(w - self.mean) / self.scale  # subgradient, sign(0) = 0
        return np.zeros_like(w)

    def hess_log_pdf(self, w: ArrayLike) -> np.ndarray:
        """The log density's Hessian, diagonal (d,): −1/σ² (gaussian), else 0 (laplace: away
        from its peak)."""
        w = np.asarray(w, dtype=float)
        return np.full_like(w, -1 / self.scale**2 if self.kind == "gaussian" else 0.0)

    def _laplace_sides(
        self,
    ) -> tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray], np.ndarray]:
        """Split the box at the Laplace peak (the mean): for the side above and the side below,
        the distance p of its near end from the mean and its length (each (d,)); and
        P(side above) (d,)."""
        a, c = self.lower - self.mean, self.upper - self.mean
        p_up, p_dn = np.maximum(a, 0.0), np.maximum(-c, 0.0)
        len_up, len_dn = np.maximum(c - p_up, 0.0), np.maximum(-a - p_dn, 0.0)
        # Side masses ∝ ∫_p^{p+L} exp(−z/b); both sides are non-empty only when the box holds
        # the mean (p = 0 on both), so the common factor exp(−p/b) can be dropped: no underflow.
        m_up, m_dn = -np.expm1(-len_up / self.scale), -np.expm1(-len_dn / self.scale)
        return (p_up, len_up), (p_dn, len_dn), m_up / (m_up + m_dn)

    def sample(self, rng: np.random.Generator, size: int | None = None) -> np.ndarray:
        """Draws from the prior truncated to the box (it factorises per dimension):
        shape (d,), or (size, d) if size is given."""
        shape = (self.dim,) if size is None else (size, self.dim)
        if self.kind == "uniform":
            return rng.uniform(self.lower, self.upper, size=shape)
        if self.kind == "gaussian":
            a, c = (self.lower - self.mean) / self.scale, (self.upper - self.mean) / self.scale
            from scipy.stats import truncnorm  # 0.25 s to import: only when it is used

            return truncnorm.rvs(a, c, loc=self.mean, scale=self.scale, size=shape,
                                 random_state=rng)
        # Laplace: pick a side by its mass, then invert the truncated exponential's CDF.
        (p_up, len_up), (p_dn, len_dn), prob_up = self._laplace_sides()
        up = rng.uniform(size=shape) < prob_up
        p, length = np.where(up, p_up, p_dn), np.where(up, len_up, len_dn)
        z = p - self.scale * np.log1p(rng.uniform(size=shape) * np.expm1(-length / self.scale))
        return np.clip(self.mean + np.where(up, z, -z), self.lower, self.upper)  # round-off

    def box_mean(self) -> np.ndarray:
        """Mean (d,) of the prior truncated to the box, per dimension."""
        if self.kind == "uniform":
            return (self.lower + self.upper) / 2
        if self.kind == "gaussian":
            a, c = (self.lower - self.mean) / self.scale, (self.upper - self.mean) / self.scale
            from scipy.stats import truncnorm

            return np.atleast_1d(truncnorm.mean(a, c, loc=self.mean, scale=self.scale))
        (p_up, len_up), (p_dn, len_dn), prob_up = self._laplace_sides()
        mean_up = p_up + _truncated_exponential_mean(len_up, self.scale)
        mean_dn = p_dn + _truncated_exponential_mean(len_dn, self.scale)
        return self.mean + prob_up * mean_up - (1 - prob_up) * mean_dn


