"""Local controllers (steer functions) that generate the edges of the navigation graph.

``linear`` joins two points by a straight segment; ``posq`` integrates the POSQ
controller for a differential-drive robot (Palmieri & Arras, IROS 2014), which is
Astolfi's polar-coordinates controller with a saturated forward speed.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike

from pipeline.core.params import (
    LARGEST_POSITIVE,
    ParameterError,
    is_number,
    require,
    require_positive,
)


def wrap_angle(a: ArrayLike) -> np.ndarray | np.float64:
    """Wrap angle(s) to (-pi, pi]; works on scalars and arrays (the result has a's shape, a
    numpy float for a scalar)."""
    a = np.asarray(a, dtype=float)
    return a - 2.0 * np.pi * np.ceil((a - np.pi) / (2.0 * np.pi))


def _wrap(a: float) -> float:
    """Scalar wrap_angle with plain floats: the POSQ loop calls it thousands of times."""
    return a - 2.0 * math.pi * math.ceil((a - math.pi) / (2.0 * math.pi))


def _as_vector(a: ArrayLike, name: str, sizes: tuple[int, ...]) -> np.ndarray:
    a = np.asarray(a, dtype=float)
    if a.ndim != 1 or a.shape[0] not in sizes:
        shapes = ' or '.join(f'({s},)' for s in sizes)
        raise ValueError(f"{name} must have shape {shapes}, got {a.shape}")
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


@dataclass(frozen=True, eq=False)
class Runs:
    """The controller runs of a batch of (start, target) pairs, flattened: run k came from
    input pair `index[k]` and drove through `points[offsets[k]:offsets[k + 1]]`."""
    index: np.ndarray  # (m,) input pairs that produced a run (the others had none)
    points: np.ndarray  # (P, 2) waypoints of all runs, run after run
    offsets: np.ndarray  # (m + 1,)
    durations: np.ndarray  # (m,) seconds
    end_poses: np.ndarray  # (m, 3) the pose each run ends in

    def __len__(self) -> int:
        return len(self.index)

    def waypoints(self, k: int) -> np.ndarray:
        """(K+1, 2) waypoints of run k."""
        return self.points[self.offsets[k]:self.offsets[k + 1]]

    def segments(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Every straight piece of every run: start points (S, 2), end points (S, 2) and the
        run each belongs to (S,)."""
        last = np.zeros(len(self.points), dtype=bool)
        last[self.offsets[1:] - 1] = True  # a run's last point starts no segment
        first = np.flatnonzero(~last)
        owner = np.repeat(np.arange(len(self)), np.diff(self.offsets) - 1)
        return self.points[first], self.points[first + 1], owner

    def subset(self, keep: np.ndarray) -> Runs:
        """The runs selected by the boolean mask (m,) or index array `keep`."""
        keep = np.arange(len(self))[keep]
        pieces = [self.waypoints(k) for k in keep]
        return Runs.from_paths(self.index[keep], pieces, self.durations[keep],
                               self.end_poses[keep])

    @staticmethod
    def from_paths(index: ArrayLike, paths: list[np.ndarray], durations: ArrayLike,
                   end_poses: ArrayLike) -> Runs:
        """Runs from their input pair indices (m,), waypoints (m arrays (K+1, 2)), durations
        (m,) and end poses (m, 3)."""
        lengths = [len(p) for p in paths]
        points = np.concatenate(paths) if paths else np.zeros((0, 2))
        return Runs(np.asarray(index, dtype=np.int64), points,
                    np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64),
                    np.asarray(durations, dtype=float).reshape(len(paths)),
                    np.asarray(end_poses, dtype=float).reshape(len(paths), 3))


class Controller(Protocol):
    """A local controller (steer function): what the adaptive graph needs of one."""

    @property
    def cruise_speed(self) -> float:
        """Typical forward speed (m/s): how far a run of t seconds gets."""
        ...

    def steer_many(self, starts: np.ndarray, targets: np.ndarray) -> Runs:
        """Runs from starts[i] to targets[i], both (n, 3) poses; pairs without a run are
        left out."""
        ...


MIN_DT = 1e-3  # s, POSQ's shortest integration step


@dataclass
class LinearController:
    speed: float = 1.0  # m/s

    def __post_init__(self) -> None:
        require_positive(self, "speed")

    @property
    def cruise_speed(self) -> float:
        return self.speed

    def steer(self, start: np.ndarray, target: np.ndarray) -> Trajectory | None:
        """Straight segment start -> target, each (2,) or (3,) (headings ignored); None if it
        has zero length."""
        p = _as_vector(start, "start", (2, 3))[:2]
        q = _as_vector(target, "target", (2, 3))[:2]
        length = float(np.hypot(*(q - p)))
        if length < 1e-9:
            return None
        heading = math.atan2(q[1] - p[1], q[0] - p[0])
        poses = np.array([[p[0], p[1], heading], [q[0], q[1], heading]])
        return Trajectory(poses, length / self.speed)

    def steer_many(self, starts: np.ndarray, targets: np.ndarray) -> Runs:
        """Straight segments between (n, 2) or (n, 3) starts and targets, vectorised; a run
        ends in the target pose as given."""
        a, b = np.asarray(starts, dtype=float), np.asarray(targets, dtype=float)
        ok = np.flatnonzero(np.linalg.norm(b[:, :2] - a[:, :2], axis=1) > 1e-9)
        a, b = a[ok], b[ok]
        points = np.stack([a[:, :2], b[:, :2]], axis=1).reshape(-1, 2)
        end_poses = b if b.shape[1] == 3 else np.column_stack([b, np.zeros(len(b))])
        return Runs(ok.astype(np.int64), points, np.arange(0, 2 * len(ok) + 1, 2),
                    np.linalg.norm(b[:, :2] - a[:, :2], axis=1) / self.speed, end_poses)


@dataclass
class PosqController:
    """POSQ steering. It stops on rho < eps alone; with the reference gains the heading error
    near the goal only decays like rho**0.29, so at eps = 0.05 a pose target's heading can be
    missed by a lot (median ~0.75 rad over a grid of starts); a smaller eps tightens it."""

    k_v: float = 3.8  # posq: gain of the forward speed
    k_rho: float = 1.0  # posq: gain on the distance to the target
    k_alpha: float = 6.0  # posq: gain on the heading error towards the target
    k_beta: float = -1.0  # posq: gain on the target's orientation error (usually < 0)
    wheel_base: float = 0.4  # posq: m
    max_speed: float = 1.0  # posq: max wheel speed, m/s
    dt: float = 0.05  # posq: s, integration step (from 0.001 to max_time)
    eps: float = 0.05  # posq: m, arrival tolerance
    max_time: float = 10.0  # posq: s, runs that take longer are dropped
    # posq: reverse while the target is behind (|alpha| > pi/2), re-decided each step.
    allow_backward: bool = False

    def __post_init__(self) -> None:
        require_positive(self, "k_v", "k_rho", "k_alpha", "wheel_base", "max_speed", "dt", "eps",
                         "max_time")
        require(is_number(self.k_beta) and abs(self.k_beta) <= LARGEST_POSITIVE, "k_beta",
                self.k_beta, f"a number within ±{LARGEST_POSITIVE:g}")  # often < 0
        # every run integrates max_time / dt steps: 1e-12 s hung growth at 7 GB
        require(MIN_DT <= self.dt <= self.max_time, "dt", self.dt,
                f"a step in seconds from {MIN_DT:g} to max_time ({self.max_time:g})")

    @property
    def cruise_speed(self) -> float:
        return self.k_rho  # v = K_ρ·tanh(K_v·ρ) ≤ K_ρ

    @property
    def max_angular_rate(self) -> float:
        """Largest |omega| the clipped wheel speeds allow (wheels at +-max_speed)."""
        return 2.0 * self.max_speed / self.wheel_base

    def steer_many(self, starts: np.ndarray, targets: np.ndarray) -> Runs:
        """One POSQ integration per pair of (n, 3) poses (targets may be (n, 2) points); a
        run ends heading along its last step."""
        index: list[int] = []
        paths: list[np.ndarray] = []
        durations: list[float] = []
        ends: list[list[float]] = []
        for i, (a, b) in enumerate(zip(starts, targets, strict=True)):
            traj = self.steer(a, b)
            if traj is None:
                continue
            pts = traj.points
            d = pts[-1] - pts[-2]
            index.append(i)
            paths.append(pts)
            durations.append(traj.duration)
            ends.append([pts[-1, 0], pts[-1, 1], math.atan2(d[1], d[0])])
        return Runs.from_paths(index, paths, durations, ends)

    def steer(self, start: np.ndarray, target: np.ndarray) -> Trajectory | None:
        """Integrate POSQ from start (3,) to target (3,) or (2,) until rho < eps; None if that
        takes longer than max_time (or the start is already within eps of the target: there
        is no edge to make)."""
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
            # Target behind: reverse, as POSQ does.
            if self.allow_backward and abs(alpha) > math.pi / 2:
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


CONTROLLERS: dict[str, type[LinearController] | type[PosqController]] = {
    "linear": LinearController, "posq": PosqController}


def make_controller(kind: str, **params: float) -> Controller:
    """The controller `kind` ('linear' or 'posq') with the given parameters."""
    if kind not in CONTROLLERS:
        raise ParameterError("kind", kind, " or ".join(repr(k) for k in CONTROLLERS))
    return CONTROLLERS[kind](**params)  # type: ignore[arg-type]
