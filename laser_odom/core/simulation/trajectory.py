"""A deterministic, smooth robot path through a world, and its timing.

The path is a closed loop of waypoints. Corners are rounded with circular fillets,
then the whole curve is smoothed with a Gaussian along its arc length so that the
curvature (hence the angular velocity ``w = v * kappa``) changes continuously
instead of stepping at the arc ends. The robot drives the loop like a differential
drive base (heading = tangent) with a speed profile that respects a cruise speed, an
angular-rate limit ``v <= w_max / |kappa|`` and an acceleration limit, and starts at
rest. The acceleration limit is applied with the classic forward-backward pass of
time-optimal path following (Bobrow, Dubowsky & Gibson, IJRR 1985), written in
closed form: ``v_i^2 = min_j (v_lim_j^2 + 2 a |s_i - s_j|)`` over the samples j
before (forward) or after (backward) i, i.e. a cumulative minimum.
"""

from __future__ import annotations

from dataclasses import dataclass
import math

import numpy as np

from laser_odom.core import se2


@dataclass(frozen=True)
class SpeedProfile:
    """Speed limits of the simulated robot."""

    mean_speed: float = 0.45
    """Cruise speed [m/s]; the cruise speed varies around it along the path."""
    speed_variation: float = 0.1
    """Amplitude [m/s] of the slow sinusoidal cruise-speed variation."""
    variation_wavelength: float = 13.0
    """Path length [m] of one period of the speed variation."""
    max_turn_rate: float = 0.5
    """Largest angular velocity [rad/s]."""
    max_acceleration: float = 0.25
    """Largest tangential acceleration and deceleration [m/s^2]."""


def fillet_polyline(waypoints: np.ndarray, radius: float, step: float) -> np.ndarray:
    """Return dense points of the closed waypoint loop with corners rounded by arcs.

    Each corner gets a circular arc of ``radius`` tangent to both legs (shrunk if a
    leg is too short); collinear waypoints pass straight through. Points are about
    ``step`` apart.
    """
    w = np.asarray(waypoints, dtype=float)
    n = len(w)
    prev_pts, next_pts = np.roll(w, 1, axis=0), np.roll(w, -1, axis=0)
    out: list[np.ndarray] = []
    entry = []
    leaves = []
    for i in range(n):
        d_in = w[i] - prev_pts[i]
        d_out = next_pts[i] - w[i]
        l_in, l_out = float(np.hypot(*d_in)), float(np.hypot(*d_out))
        u_in, u_out = d_in / l_in, d_out / l_out
        turn = math.atan2(u_in[0] * u_out[1] - u_in[1] * u_out[0], float(u_in @ u_out))
        if abs(turn) < 1e-9:
            entry.append(w[i])
            leaves.append(w[i])
            out.append(np.zeros((0, 2)))
            continue
        tangent = min(radius * math.tan(0.5 * abs(turn)), 0.5 * l_in, 0.5 * l_out)
        r = tangent / math.tan(0.5 * abs(turn))
        start = w[i] - tangent * u_in
        normal = np.array([-u_in[1], u_in[0]]) * math.copysign(1.0, turn)
        centre = start + r * normal
        a0 = math.atan2(start[1] - centre[1], start[0] - centre[0])
        count = max(int(math.ceil(r * abs(turn) / step)), 2)
        a = a0 + np.linspace(0.0, turn, count)
        out.append(np.column_stack((centre[0] + r * np.cos(a), centre[1] + r * np.sin(a))))
        entry.append(start)
        leaves.append(w[i] + tangent * u_out)
    pieces = []
    for i in range(n):
        arc = out[i]
        pieces.append(arc if len(arc) else entry[i][None, :])
        a, b = leaves[i], entry[(i + 1) % n]
        length = float(np.hypot(*(b - a)))
        count = max(int(math.ceil(length / step)), 1)
        alpha = np.linspace(0.0, 1.0, count + 1)[1:-1, None]
        pieces.append(a + alpha * (b - a))
    return np.vstack(pieces)


def _resample_closed(points: np.ndarray, step: float) -> tuple[np.ndarray, float]:
    """Resample a closed curve at equal arc-length steps; return points and length."""
    loop = np.vstack((points, points[:1]))
    seg = np.hypot(*np.diff(loop, axis=0).T)
    s = np.concatenate(([0.0], np.cumsum(seg)))
    length = float(s[-1])
    count = int(round(length / step))
    grid = np.arange(count) * (length / count)
    resampled = np.column_stack((np.interp(grid, s, loop[:, 0]), np.interp(grid, s, loop[:, 1])))
    return resampled, length


def _smooth_closed(points: np.ndarray, sigma_samples: float) -> np.ndarray:
    """Convolve a closed curve's coordinates with a normalised Gaussian (wrapping)."""
    half = int(math.ceil(4.0 * sigma_samples))
    if half < 1:
        return points.copy()
    k = np.exp(-0.5 * (np.arange(-half, half + 1) / sigma_samples) ** 2)
    k /= k.sum()
    padded = np.vstack((points[-half:], points, points[:half]))
    return np.column_stack([np.convolve(padded[:, j], k, mode='valid') for j in range(2)])


class SmoothPath:
    """A closed, smooth loop driven repeatedly from rest, sampled at any times.

    The first waypoint must lie in the middle of a straight leg (collinear with its
    neighbours, farther than the smoothing from any corner) so that the robot starts
    exactly there with the heading of that leg.
    """

    def __init__(self, waypoints: np.ndarray, corner_radius: float = 1.0,
                 smoothing: float = 0.25, speed: SpeedProfile = SpeedProfile(),
                 step: float = 0.01) -> None:
        """Build the loop geometry (arc-length grid, heading, curvature)."""
        self.waypoints = np.asarray(waypoints, dtype=float)
        self.speed = speed
        self.step = step
        dense = fillet_polyline(self.waypoints, corner_radius, 0.5 * step)
        dense, _ = _resample_closed(dense, step)
        dense = _smooth_closed(dense, smoothing / step)
        self.points, self.length = _resample_closed(dense, step)
        self.ds = self.length / len(self.points)
        fwd = np.roll(self.points, -1, axis=0) - np.roll(self.points, 1, axis=0)
        self.heading = np.arctan2(fwd[:, 1], fwd[:, 0])
        dtheta = se2.wrap_angle(np.roll(self.heading, -1) - np.roll(self.heading, 1))
        self.curvature = dtheta / (2.0 * self.ds)
        self._timing_cache: tuple[float, np.ndarray, np.ndarray] | None = None

    def _timing(self, duration: float) -> tuple[np.ndarray, np.ndarray]:
        """Return the unrolled arc length grid and the time at each of its samples."""
        if self._timing_cache is not None and self._timing_cache[0] >= duration:
            return self._timing_cache[1], self._timing_cache[2]
        sp = self.speed
        top = sp.mean_speed + abs(sp.speed_variation)
        laps = int(math.ceil((duration * top + 1.0) / self.length)) + 1
        n = len(self.points)
        s = np.arange(laps * n + 1) * self.ds
        kappa = np.abs(np.resize(self.curvature, s.shape[0]))
        cruise = sp.mean_speed + sp.speed_variation * np.sin(
            2.0 * math.pi * s / sp.variation_wavelength)
        with np.errstate(divide='ignore'):
            limit = np.minimum(cruise, sp.max_turn_rate / kappa)
        limit[0] = 0.0
        two_a = 2.0 * sp.max_acceleration
        v2 = limit ** 2
        v2 = np.minimum(v2, two_a * s + np.minimum.accumulate(v2 - two_a * s))
        v2 = np.minimum(v2, -two_a * s + np.minimum.accumulate((v2 + two_a * s)[::-1])[::-1])
        v = np.sqrt(np.maximum(v2, 0.0))
        dt = 2.0 * self.ds / np.maximum(v[1:] + v[:-1], 1e-9)
        t = np.concatenate(([0.0], np.cumsum(dt)))
        self._timing_cache = (duration, s, t)
        return s, t

    def arc_length_at(self, times: np.ndarray) -> np.ndarray:
        """Return the distance driven (unrolled over laps) at each time [s]."""
        times = np.asarray(times, dtype=float)
        s, t = self._timing(float(np.max(times, initial=0.0)))
        return np.interp(times, t, s)

    def poses_at(self, times: np.ndarray) -> np.ndarray:
        """Return the (N, 3) poses ``[x, y, heading]`` at ``times`` [s] from the start."""
        s = np.mod(self.arc_length_at(times), self.length)
        grid = np.arange(len(self.points) + 1) * self.ds
        loop = np.vstack((self.points, self.points[:1]))
        x = np.interp(s, grid, loop[:, 0])
        y = np.interp(s, grid, loop[:, 1])
        c = np.interp(s, grid, np.append(np.cos(self.heading), np.cos(self.heading[0])))
        si = np.interp(s, grid, np.append(np.sin(self.heading), np.sin(self.heading[0])))
        return np.column_stack((x, y, np.arctan2(si, c)))

    def speeds_at(self, times: np.ndarray, dt: float = 1e-3) -> tuple[np.ndarray, np.ndarray]:
        """Return the forward speed [m/s] and turn rate [rad/s] at ``times`` (differences)."""
        times = np.asarray(times, dtype=float)
        a, b = self.poses_at(np.maximum(times - dt, 0.0)), self.poses_at(times + dt)
        span = times + dt - np.maximum(times - dt, 0.0)
        v = np.hypot(b[:, 0] - a[:, 0], b[:, 1] - a[:, 1]) / span
        w = se2.wrap_angle(b[:, 2] - a[:, 2]) / span
        return v, w
