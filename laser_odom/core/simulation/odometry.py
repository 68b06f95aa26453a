"""Simulated wheel odometry: ground-truth increments corrupted by systematic and random error.

The error model follows the usual account of differential-drive odometry error
(Borenstein & Feng, "Measurement and correction of systematic odometry errors in
mobile robots", IEEE T-RA 1996): systematic errors from a wrong wheel diameter
(distance scale), unequal wheel diameters (a constant curvature bias, i.e. yaw drift
per metre) and a wrong wheel base (turn scale), plus random errors whose variance
grows linearly with the distance driven and the angle turned (a random walk, so the
statistics do not depend on the odometry rate).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from laser_odom.core import se2
from laser_odom.core.trajectory import Trajectory


@dataclass(frozen=True)
class OdometryNoise:
    """Error model of the simulated wheel odometry (defaults: a typical indoor base)."""

    scale_error: float = 0.01
    """Relative error of every distance (wheel diameter) [-]."""
    turn_scale_error: float = 0.02
    """Relative error of every rotation (wheel base) [-]."""
    yaw_drift: float = 0.002
    """Yaw added per metre driven (unequal wheels) [rad/m]."""
    translation_sigma: float = 0.01
    """Random translation error, standard deviation per sqrt(metre) [m/sqrt(m)]."""
    rotation_sigma: float = 0.01
    """Random yaw error per sqrt(radian) turned [rad/sqrt(rad)]."""
    rotation_per_distance_sigma: float = 0.005
    """Random yaw error per sqrt(metre) driven [rad/sqrt(m)]."""

    def scaled(self, factor: float) -> 'OdometryNoise':
        """Return the model with every error multiplied by ``factor`` (0: perfect)."""
        return replace(self, **{k: getattr(self, k) * factor
                                for k in self.__dataclass_fields__})


def wheel_odometry(truth: Trajectory, noise: OdometryNoise,
                   rng: np.random.Generator) -> Trajectory:
    """Return the odometry a wheel encoder integration would report along ``truth``.

    Each ground-truth step ``relative(T_k, T_k+1)`` is corrupted in the base frame and
    the corrupted steps are composed from the first true pose, so the error drifts
    without bound like real dead reckoning. Composition is vectorised: headings are
    a cumulative sum of the noisy turns, positions a cumulative sum of the rotated
    noisy steps.
    """
    n = len(truth)
    if n == 0:
        return Trajectory()
    poses = truth.poses
    c, s = np.cos(poses[:-1, 2]), np.sin(poses[:-1, 2])
    d = np.diff(poses, axis=0)
    dx = c * d[:, 0] + s * d[:, 1]
    dy = -s * d[:, 0] + c * d[:, 1]
    dtheta = se2.wrap_angle(d[:, 2])
    dist = np.hypot(dx, dy)
    turn = np.abs(dtheta)
    gauss = rng.standard_normal((n - 1, 3))
    scale = 1.0 + noise.scale_error
    dx_n = dx * scale + gauss[:, 0] * noise.translation_sigma * np.sqrt(dist)
    dy_n = dy * scale + gauss[:, 1] * noise.translation_sigma * np.sqrt(dist)
    dtheta_n = (dtheta * (1.0 + noise.turn_scale_error) + noise.yaw_drift * dist
                + gauss[:, 2] * np.sqrt(noise.rotation_sigma ** 2 * turn
                                        + noise.rotation_per_distance_sigma ** 2 * dist))
    out = np.empty_like(poses)
    out[0] = poses[0]
    heading = poses[0, 2] + np.concatenate(([0.0], np.cumsum(dtheta_n)))
    ch, sh = np.cos(heading[:-1]), np.sin(heading[:-1])
    out[1:, 0] = poses[0, 0] + np.cumsum(ch * dx_n - sh * dy_n)
    out[1:, 1] = poses[0, 1] + np.cumsum(sh * dx_n + ch * dy_n)
    out[:, 2] = se2.wrap_angle(heading)
    return Trajectory(truth.stamps_ns.copy(), out)
