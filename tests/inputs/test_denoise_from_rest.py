"""A tracked walk that sets off from rest, densely sampled, smoothed of its tracking noise
(pipeline/inputs/denoise.py `smooth_to_noise`): its first point is kept and the smoothed
walk goes on from there. The free smoother's solution is a straight line near each end,
which an accelerating walk leaves behind its first point; with that first point written
over it, a 100 Hz walk with 2 cm of noise began with a 13 cm hook away from the goal, read
by learning as goal deviation (its weight went to the box's bound, 0)."""

import numpy as np

from pipeline.inputs.denoise import (
    noise_sigma,
    smooth_all_to_noise,
    smooth_jitter,
    smooth_to_noise,
    whittaker,
)

START, GOAL = np.array([0.5, 0.5]), np.array([5.5, 9.0])


def walk_from_rest(rate: float = 100.0, speed: float = 1.25, ramp: float = 0.8) -> np.ndarray:
    """From START towards GOAL at `rate` Hz, accelerating from rest to `speed` over `ramp`
    seconds, then at that speed until 0.3 m before the goal."""
    heading = (GOAL - START) / np.linalg.norm(GOAL - START)
    total = np.linalg.norm(GOAL - START) - 0.3
    t = np.arange(0.0, 20.0, 1.0 / rate)
    s = np.where(t < ramp, 0.5 * speed / ramp * t ** 2, speed * (t - ramp / 2))
    s = s[s <= total]
    return START + s[:, None] * heading


def goal_deviation(points: np.ndarray) -> float:
    """The total increase of the distance to the goal along the points (the feature)."""
    return float(np.maximum(np.diff(np.linalg.norm(points - GOAL, axis=1)), 0.0).sum())


def test_a_walk_from_rest_is_smoothed_without_a_hook_at_its_start():
    true = walk_from_rest()
    raw = true + np.random.default_rng(3).normal(0.0, 0.02, true.shape)
    (out,), (smoothed,), _ = smooth_jitter([raw], "x")
    assert smoothed
    assert np.array_equal(out[[0, -1]], raw[[0, -1]])
    # nowhere more than the noise farther from the goal than where it began (13 cm before)
    start_gap = np.linalg.norm(raw[0] - GOAL)
    assert np.linalg.norm(out - GOAL, axis=1).max() < start_gap + 0.02
    assert goal_deviation(out) < 0.03  # 0.21 m before
    true_length = np.linalg.norm(np.diff(true, axis=0), axis=1).sum()
    assert np.linalg.norm(np.diff(out, axis=0), axis=1).sum() < 1.01 * true_length


def test_kept_ends_minimise_the_same_sum_given_them():
    rng = np.random.default_rng(0)
    for n in (4, 5, 30):
        y = rng.normal(size=(n, 2))
        D = np.diff(np.eye(n), 2, axis=0)
        A = np.eye(n) + 7.3 * D.T @ D
        inner = np.arange(1, n - 1)
        expected = y.copy()
        expected[inner] = np.linalg.solve(A[np.ix_(inner, inner)],
                                          y[inner] - A[np.ix_(inner, [0, n - 1])] @ y[[0, -1]])
        np.testing.assert_allclose(whittaker(y, 7.3), expected, atol=1e-12)
    raw = walk_from_rest() + np.random.default_rng(4).normal(0.0, 0.02, (1, 2))
    assert noise_sigma([raw]) < 1e-3  # no noise read: nothing to smooth
    np.testing.assert_array_equal(smooth_to_noise(raw, 0.0), raw)


def test_smoothing_many_at_once_gives_each_one_s_bits():
    """`smooth_all_to_noise` runs the tracks' bisections side by side in one banded solve a
    step: each track comes out bit for bit as `smooth_to_noise` makes it on its own."""
    rng = np.random.default_rng(5)
    tracks, sigmas = [], []
    for n in (4, 5, 6, 30, 2, 3, 250, 4, 1000, 17):
        walk = np.cumsum(rng.normal(0.0, 0.05, (n, 2)), axis=0) + rng.uniform(-1e5, 1e5, 2)
        tracks.append(walk + rng.normal(0.0, 0.02, walk.shape))
        sigmas.append(float(rng.choice([0.0, 0.005, 0.02, 0.3])) if n != 250 else 0.02)
    tracks.append(walk_from_rest() + rng.normal(0.0, 0.02, (1, 2)))
    sigmas.append(0.02)
    together = smooth_all_to_noise(tracks, sigmas)
    for track, sigma, out in zip(tracks, sigmas, together, strict=True):
        assert out.tobytes() == smooth_to_noise(track, sigma).tobytes()
    assert smooth_all_to_noise([], []) == []


def test_means_over_decide_as_np_mean_of_each_track():
    # the means of all tracks at once decide as np.mean of each alone, also at a limit that
    # is np.mean's own value (where another order of sums may fall either side of it)
    from pipeline.inputs.denoise import _means_over

    rng = np.random.default_rng(7)
    n = rng.integers(4, 400, 300)
    begin = np.cumsum(n) - n
    square = rng.random((n.sum(), 2)) ** 4
    exact = np.array([np.mean(square[b:b + k]) for b, k in zip(begin, n, strict=True)])
    limits = exact * np.where(np.arange(len(n)) % 3 == 0, 1.0, rng.uniform(0.9, 1.1, len(n)))
    limits[1::3] = np.nextafter(exact[1::3], 0)
    assert (_means_over(square, begin, n, limits) == (exact > limits)).all()


def test_smooth_to_noise_bisects_the_log_penalty_30_times_over_minus_4_to_12():
    """`smooth_to_noise` is the Whittaker smoother (`whittaker`, checked against a dense
    solve above) at the penalty a plain bisection finds: 30 halvings of 10^-4..10^12, a
    departure (np.mean of the squares, about the first point) over (DISCREPANCY sigma)^2
    lowering the upper bound, the lower bound's smoothing given; a polyline of 4 points is
    smoothed too. Written here a track and a step at a time: the same bits."""
    from pipeline.inputs.denoise import DISCREPANCY

    rng = np.random.default_rng(11)
    for n, sigma, offset in ((4, 0.3, 0.0), (7, 0.05, 3.0e5), (60, 0.02, -1.0e3)):
        points = np.cumsum(rng.normal(0.0, 0.05, (n, 2)), axis=0) + offset
        points += rng.normal(0.0, sigma, points.shape)
        q = points - points[0]
        low, high = -4.0, 12.0
        for _ in range(30):
            mid = (low + high) / 2
            if np.mean((whittaker(q, 10.0 ** mid) - q) ** 2) > (DISCREPANCY * sigma) ** 2:
                high = mid
            else:
                low = mid
        expected = whittaker(q, 10.0 ** low) + points[0]
        assert not np.array_equal(expected, points)  # smoothed: the test tells
        assert smooth_to_noise(points, sigma).tobytes() == expected.tobytes()
        [together] = smooth_all_to_noise([points], [sigma])
        assert together.tobytes() == expected.tobytes()
