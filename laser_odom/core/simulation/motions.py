"""How the simulated robot drives its world's loop: motion profiles by name.

- ``gentle``: the loop at about 0.45 m/s, turning at most 0.5 rad/s, accelerating at
  most 0.25 m/s^2 - a careful indoor base (:class:`SpeedProfile` defaults).
- ``spin``: the gentle loop, but every few seconds the robot stops and turns in place
  - a full turn, three quarters back, a half turn, ... - at up to 3 rad/s with sharp
  starts and stops (20 rad/s^2): exploring, relocalising, a joystick.
- ``aggressive``: up to 1.5 m/s, speeding up and slowing down every few metres at up
  to 1.5 m/s^2 and turning at up to 2 rad/s.
- ``fast``: a fast robot's steady run, 1 m/s, turning the corners at up to 1.5 rad/s
  and accelerating at up to 1 m/s^2: with a 5 Hz lidar, 0.2 m and up to 17 deg
  between scans (the ``campus`` and ``hall`` loops have corners tight enough to
  reach the turn-rate limit).

A profile maps times to poses (``poses_at``), like :class:`SmoothPath`, which the
simulator samples at the scan and odometry stamps and, for a sweeping lidar, at the
time of every beam. :class:`ConstantTwist` is a known motion for tests (a constant
speed and turn rate), which :func:`~laser_odom.core.simulation.simulate` accepts in
place of a profile name.
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Protocol

import numpy as np

from laser_odom.core import se2
from laser_odom.core.simulation.trajectory import SmoothPath, SpeedProfile
from laser_odom.core.simulation.world import World

MOTIONS = ('gentle', 'spin', 'aggressive', 'fast')
"""Motion profile names (``laser_odom_simulate --motion``)."""

DEFAULT_MOTION = 'gentle'

AGGRESSIVE = SpeedProfile(mean_speed=1.0, speed_variation=0.5, variation_wavelength=4.0,
                          max_turn_rate=2.0, max_acceleration=1.5)
"""Speed limits of the ``aggressive`` profile: 0.5-1.5 m/s cruise, changing every 2 m."""

FAST = SpeedProfile(mean_speed=1.0, speed_variation=0.0, max_turn_rate=1.5,
                    max_acceleration=1.0)
"""Speed limits of the ``fast`` profile: 1 m/s cruise, 1.5 rad/s in the corners."""


class UnknownMotionError(ValueError):
    """Raised for a motion profile name that is not known."""


class Motion(Protocol):
    """Anything that gives the robot's pose at given times."""

    def poses_at(self, times: np.ndarray) -> np.ndarray:
        """Return the (N, 3) poses ``[x, y, heading]`` at ``times`` [s] from the start."""


@dataclass(frozen=True)
class SpinSchedule:
    """When and how the ``spin`` profile turns in place."""

    drive: float = 4.0
    """Seconds of driving between two spins."""
    ramp: float = 0.5
    """Seconds to slow down to a stop before a spin, and to speed up after it."""
    max_rate: float = 3.0
    """Largest turn rate of a spin [rad/s]."""
    acceleration: float = 20.0
    """Angular acceleration at the start and end of a spin [rad/s^2]."""
    turns: tuple[float, ...] = (2.0 * math.pi, -1.5 * math.pi, math.pi, -2.0 * math.pi)
    """Angles of the successive spins [rad], repeated."""


def turn_rate_profile(angle: float, max_rate: float, acceleration: float,
                      step: float) -> np.ndarray:
    """Return the turn rate, sampled every ``step`` s, of a rest-to-rest turn by ``angle``.

    Trapezoidal: accelerate at ``acceleration`` to ``max_rate`` (or less, for a short
    turn), hold, decelerate; the samples are scaled so they integrate to ``angle``.
    """
    magnitude = abs(angle)
    peak = min(max_rate, math.sqrt(magnitude * acceleration))
    ramp = peak / acceleration
    hold = max(magnitude / peak - ramp, 0.0)
    total = 2.0 * ramp + hold
    t = np.arange(int(math.ceil(total / step)) + 1) * step
    rate = np.minimum.reduce([peak * np.ones_like(t), acceleration * t,
                              acceleration * np.maximum(total - t, 0.0)])
    area = float(np.sum(rate) * step)
    return math.copysign(1.0, angle) * rate * (magnitude / area if area > 0 else 0.0)


class SpinningPath:
    """A path driven with stops to spin in place (the ``spin`` profile).

    The robot's progress along ``path`` runs on a warped clock: at rate 1 while it
    drives, ramping linearly to 0 before each spin and back to 1 after it, frozen
    while it spins. The spins add to the heading. Both are tabulated on a fine time
    grid and interpolated.
    """

    STEP = 1e-3
    """Time step [s] of the tabulated clock and heading offset."""

    def __init__(self, path: SmoothPath, schedule: SpinSchedule = SpinSchedule()) -> None:
        """Drive ``path`` with the spins of ``schedule``."""
        self.path = path
        self.schedule = schedule
        self._table: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None

    def _tabulate(self, duration: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Return times, path clock and heading offset covering ``duration`` seconds."""
        if self._table is not None and self._table[0][-1] >= duration:
            return self._table
        sched, step = self.schedule, self.STEP
        rates, turns = [], []
        ramp = np.linspace(1.0, 0.0, int(round(sched.ramp / step)), endpoint=False)
        spin_index, elapsed = 0, 0.0
        while elapsed <= duration + sched.drive:
            drive = np.ones(int(round(sched.drive / step)))
            spin = turn_rate_profile(sched.turns[spin_index % len(sched.turns)],
                                     sched.max_rate, sched.acceleration, step)
            spin_index += 1
            clock = np.concatenate((drive, ramp, np.zeros(len(spin)), ramp[::-1]))
            turn = np.concatenate((np.zeros(len(drive) + len(ramp)), spin,
                                   np.zeros(len(ramp))))
            rates.append(clock)
            turns.append(turn)
            elapsed += len(clock) * step
        rate, turn = np.concatenate(rates), np.concatenate(turns)
        times = np.arange(len(rate) + 1) * step
        clock = np.concatenate(([0.0], np.cumsum(rate) * step))
        heading = np.concatenate(([0.0], np.cumsum(turn) * step))
        self._table = (times, clock, heading)
        return self._table

    def poses_at(self, times: np.ndarray) -> np.ndarray:
        """Return the (N, 3) poses at ``times`` [s] from the start."""
        times = np.asarray(times, dtype=float)
        grid, clock, heading = self._tabulate(float(np.max(times, initial=0.0)))
        poses = self.path.poses_at(np.interp(times, grid, clock))
        poses[:, 2] = se2.wrap_angle(poses[:, 2] + np.interp(times, grid, heading))
        return poses


@dataclass(frozen=True)
class ConstantTwist:
    """Driving at a constant forward speed and turn rate from a start pose (exact arcs).

    A known motion for tests: ``v`` [m/s] along the heading, ``w`` [rad/s] about z,
    from ``start`` ``[x, y, heading]`` at time 0 (also before it: negative times run
    the motion backwards).
    """

    v: float = 0.0
    w: float = 0.0
    start: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def poses_at(self, times: np.ndarray) -> np.ndarray:
        """Return the (N, 3) poses at ``times`` [s] from the start."""
        t = np.asarray(times, dtype=float).reshape(-1)
        x0, y0, h0 = self.start
        heading = h0 + self.w * t
        if self.w == 0.0:
            dx, dy = self.v * t * math.cos(h0), self.v * t * math.sin(h0)
        else:
            radius = self.v / self.w
            dx = radius * (np.sin(heading) - math.sin(h0))
            dy = radius * (math.cos(h0) - np.cos(heading))
        return np.column_stack((x0 + dx, y0 + dy, se2.wrap_angle(heading)))


def motion_profile(world: World, name: str = DEFAULT_MOTION) -> Motion:
    """Return how the robot drives ``world``'s loop under the named profile."""
    if name == 'gentle':
        return world.path
    if name == 'spin':
        return SpinningPath(world.path)
    if name == 'aggressive':
        return SmoothPath(world.waypoints, world.corner_radius, speed=AGGRESSIVE)
    if name == 'fast':
        return SmoothPath(world.waypoints, world.corner_radius, speed=FAST)
    raise UnknownMotionError(
        f'unknown motion {name!r}; valid names: {", ".join(MOTIONS)}')
