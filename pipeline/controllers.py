"""Local controllers (steer functions) that generate the edges of the navigation graph.

``linear`` joins two points by a straight segment; ``posq`` integrates the POSQ
controller for a differential-drive robot (Palmieri & Arras, IROS 2014), which is
Astolfi's polar-coordinates controller with a saturated forward speed.
"""
from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

import numpy as np


def wrap_angle(a):
    """Wrap angle(s) to (-pi, pi]; works on scalars and arrays."""
    a = np.asarray(a, dtype=float)
    return a - 2.0 * np.pi * np.ceil((a - np.pi) / (2.0 * np.pi))


def _wrap(a: float) -> float:
    """Scalar wrap_angle with plain floats: the POSQ loop calls it thousands of times."""
    return a - 2.0 * math.pi * math.ceil((a - math.pi) / (2.0 * math.pi))


def _require_positive(obj, *names: str) -> None:
    for name in names:
        value = getattr(obj, name)
        ok = isinstance(value, numbers.Real) and not isinstance(value, bool)
        if not (ok and math.isfinite(value) and value > 0):
            raise ValueError(f"{type(obj).__name__}: {name} must be a positive number, got {value!r}")


def _as_vector(a, name: str, sizes: tuple[int, ...]) -> np.ndarray:
    a = np.asarray(a, dtype=float)
    if a.ndim != 1 or a.shape[0] not in sizes:
        raise ValueError(f"{name} must have shape {' or '.join(f'({s},)' for s in sizes)}, got {a.shape}")
    return a


@dataclass(frozen=True)
class Trajectory:
    poses: np.ndarray  # (K+1, 3) x, y, theta; poses[0] is the start, poses[-1] the end
    duration: float  # seconds

    @property
    def points(self) -> np.ndarray:
        return self.poses[:, :2]

    @property
    def length(self) -> float:
        return float(np.linalg.norm(np.diff(self.points, axis=0), axis=1).sum())


@dataclass(frozen=True)
class LinearController:
    speed: float = 1.0  # m/s

    def __post_init__(self):
        _require_positive(self, "speed")

    def steer(self, start: np.ndarray, target: np.ndarray) -> Trajectory | None:
        """Straight segment start -> target (headings ignored); None if it has zero length."""
        p = _as_vector(start, "start", (2, 3))[:2]
        q = _as_vector(target, "target", (2, 3))[:2]
        length = float(np.hypot(*(q - p)))
        if length < 1e-9:
            return None
        heading = math.atan2(q[1] - p[1], q[0] - p[0])
        poses = np.array([[p[0], p[1], heading], [q[0], q[1], heading]])
        return Trajectory(poses, length / self.speed)

    def steer_many(self, starts: np.ndarray, targets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Vectorised lengths and durations for (n, 2) starts/targets (zero-length rows give 0)."""
        d = np.asarray(targets, dtype=float)[:, :2] - np.asarray(starts, dtype=float)[:, :2]
        lengths = np.hypot(d[:, 0], d[:, 1])
        return lengths, lengths / self.speed


@dataclass(frozen=True)
class PosqController:
    """POSQ steering. It stops on rho < eps alone; with the reference gains the heading error
    near the goal only decays like rho**0.29, so at eps = 0.05 a pose target's heading can be
    missed by a lot (median ~0.75 rad over a grid of starts); a smaller eps tightens it."""

    k_v: float = 3.8
    k_rho: float = 1.0
    k_alpha: float = 6.0
    k_beta: float = -1.0
    wheel_base: float = 0.4
    max_speed: float = 1.0  # max wheel speed, m/s
    dt: float = 0.05
    eps: float = 0.05
    max_time: float = 30.0
    allow_backward: bool = False  # reverse while the target is behind (|alpha| > pi/2), re-decided each step

    def __post_init__(self):
        _require_positive(self, "k_v", "k_rho", "wheel_base", "max_speed", "dt", "eps", "max_time")

    @property
    def max_angular_rate(self) -> float:
        """Largest |omega| the clipped wheel speeds allow (wheels at +-max_speed)."""
        return 2.0 * self.max_speed / self.wheel_base

    def steer(self, start: np.ndarray, target: np.ndarray) -> Trajectory | None:
        """Integrate POSQ from start until rho < eps; None if that takes longer than max_time
        (or the start is already within eps of the target: there is no edge to make)."""
        x, y, th = (float(c) for c in _as_vector(start, "start", (3,)))
        target = _as_vector(target, "target", (2, 3))
        xg, yg = float(target[0]), float(target[1])
        # A bare point gets the start->target bearing as heading, i.e. "arrive going straight on".
        thg = float(target[2]) if target.size == 3 else math.atan2(yg - y, xg - x)
        half_b, dt = 0.5 * self.wheel_base, self.dt
        th = _wrap(th)
        poses = [(x, y, th)]
        max_steps = int(math.ceil(self.max_time / dt - 1e-9))
        while (rho := math.hypot(xg - x, yg - y)) >= self.eps:
            if len(poses) > max_steps:
                return None  # rho < eps not reached within max_time
            alpha = _wrap(math.atan2(yg - y, xg - x) - th)  # target direction relative to heading
            v = self.k_rho * math.tanh(self.k_v * rho)
            if self.allow_backward and abs(alpha) > math.pi / 2:  # target behind: reverse, as POSQ does
                v, alpha = -v, _wrap(alpha + math.pi)
            # beta = goal heading relative to the bearing line, theta_g - (theta + alpha) (as in the
            # original POSQ code). With k_beta < 0 the robot leads past the bearing line on the side
            # away from theta_g, so the path curves in along theta_g; k_beta > 0 would diverge.
            beta = _wrap(thg - th - alpha)
            omega = self.k_alpha * alpha + self.k_beta * beta
            # Clip wheel speeds by a common factor so the commanded curvature omega / v is kept.
            scale = (abs(v) + abs(omega) * half_b) / self.max_speed  # = max(|v_l|, |v_r|) / max
            if scale > 1.0:
                v, omega = v / scale, omega / scale
            # Exact unicycle step for constant (v, omega): the arc's chord, along the mid heading.
            half_turn = 0.5 * omega * dt
            chord = v * dt * (math.sin(half_turn) / half_turn if abs(half_turn) > 1e-12 else 1.0)
            x, y = x + chord * math.cos(th + half_turn), y + chord * math.sin(th + half_turn)
            th = _wrap(th + omega * dt)
            poses.append((x, y, th))
        if len(poses) == 1:
            return None
        return Trajectory(np.array(poses), (len(poses) - 1) * self.dt)


def make_controller(kind: str, **params) -> LinearController | PosqController:
    if kind == "linear":
        return LinearController(**params)
    if kind == "posq":
        return PosqController(**params)
    raise ValueError(f"controller must be 'linear' or 'posq', got {kind!r}")
