"""Where else the matcher stops when its start is moved a little: the other basins.

A match from a trusted prediction reports the curvature of its cost at the pose where
it stopped. Along a corridor the cost is almost flat between door frames and niches,
and its small bumps hold the matcher near wherever it starts: from the prediction it
stops at one bump, from a start a few centimetres further on at another. The
curvature then says millimetres while the pose is only known to within those bumps,
and the error repeats the prediction's, step after step. Measured on Intel (plicp,
copy 2, scans 3401-3420), the 19 steps along a corridor were each published with 5-7
mm (a few with 3-4 cm) along it, and summed to 0.53 m where the robot drove 1.01 m.
Started 5 cm further along instead, 12 of the 19 matches stopped 2-5 cm further. The
result was a failed step that the covariance did not cover (silent).

ICP's curvature-based covariance describes one basin of the cost only (Censi, "An
accurate closed-form estimate of ICP's covariance", ICRA 2007). The check here
therefore runs the matcher again, from the prediction moved both ways along the
direction the match constrains least. Each start is :data:`SHIFT_SIGMAS` of the
match's own standard deviations away, at least :data:`MIN_SHIFT`: if the curvature
told the whole story, the matcher would come back from there. A start from which it
stops elsewhere, with a match that passes the checks a match from a prediction must
pass, found another basin that fits as well. The published covariance then covers
it (:func:`.acceptance.published_covariance`), the way it covers the
alternatives of an ambiguous search. The pose and the status stay as they were: the
scans do not say which basin is right.
Only a match whose weakest direction is already weak (standard deviation above
:data:`CHECKED_SIGMA`) is checked, so a well-pinned match costs no second run.

A prediction that repeats a step not well constrained carries that step's error
(:meth:`.Registrar.expect`): it may be off by as much, and a match from it that
returns from a few of its own standard deviations proves only its own basin. The
starts then lie as many of the carried error's standard deviations along the weakest
direction away, where that is farther (intel's keyframes 0.1 s apart, plicp against
the local map, copy 1, scan 109: 2.5 cm from a prediction that repeated a step 0.7 m
short, published 6 cm certain where the robot had moved 0.74 m further, NEES 75; the
start 0.93 m on reaches another basin).
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from laser_odom.core import se2
from laser_odom.core.events import EventLog
from laser_odom.core.matchers import MatchResult
from laser_odom.core.uncertainty.degeneracy import degenerate_directions, metric_scale
from laser_odom.core.uncertainty.pose_uncertainty import nees

CHECKED_SIGMA = 0.01
"""A match whose weakest direction (metric units: rotation as the arc at the scan's RMS
range) has a standard deviation above this [m] is matched again from two starts."""

SHIFT_SIGMAS = 3.0
"""Each start is this many of the match's standard deviations along its weakest
direction away from the prediction, or as many of the error the prediction carries
there from a step not well constrained (:meth:`.Registrar.expect`), whichever is
larger."""

MIN_SHIFT = 0.02
"""Smallest shift of a start [m, metric units]."""


def other_basins(rematch: Callable[[se2.Pose], MatchResult | None], match: MatchResult,
                 guess: se2.Pose, length_scale: float,
                 carried: np.ndarray | None = None) -> list[np.ndarray]:
    """Return the poses the matcher stops at from starts moved off ``guess`` (see module).

    ``rematch`` runs the matcher from a start and returns its match, or None when that
    match fails the checks of a match from a prediction (it is no basin that fits as
    well). ``match`` is the match from ``guess``, the prediction; ``carried`` the
    covariance of the error the prediction carries beyond its measured one (zero or
    None: the starts depend on ``match`` alone). Empty when ``match``
    is pinned well enough not to be checked; poses that coincide with ``match``'s add
    nothing where they are covered.
    """
    values, vectors, _ = degenerate_directions(match.information, length_scale, 0.0)
    weakest = int(np.argmin(values))
    if values[weakest] >= CHECKED_SIGMA ** -2:
        return []
    scale = metric_scale(length_scale)
    shift = max(MIN_SHIFT, SHIFT_SIGMAS / np.sqrt(max(values[weakest], 1e-300)))
    if carried is not None:
        along = vectors[:, weakest] / scale  # the metric coordinate along it, in [x, y, theta]
        shift = max(shift, SHIFT_SIGMAS * float(np.sqrt(max(along @ carried @ along, 0.0))))
    step = shift * scale * vectors[:, weakest]
    basins = []
    for start in (np.asarray(guess, dtype=float) + step, np.asarray(guess, dtype=float) - step):
        start[2] = se2.wrap_angle(start[2])
        landed = rematch(start)
        if landed is not None:
            basins.append(landed.pose.copy())
    return basins


def record_other_basins(match: MatchResult, basins: list[np.ndarray], events: EventLog) -> None:
    """Keep ``basins`` in ``match.extra['basins']``, which the published covariance covers.

    :func:`.acceptance.published_covariance`; counted as ``other_basin`` when one lies
    elsewhere: beyond one standard deviation of the match's own covariance. A start
    that came back to the same basin stops within the matcher's convergence tolerance
    of the match, not exactly on it, and is not counted.
    """
    if not basins:
        return
    match.extra['basins'] = basins
    if any(nees(pose - match.pose, match.covariance) > 1.0 for pose in basins):
        events.count('other_basin')
