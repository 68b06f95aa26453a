"""The one interface every scan matcher implements, and the result it returns.

A matcher estimates the pose of the *current* scan in the frame of the *reference*
scan: the rigid motion ``T`` with ``q ~= R p + t`` for a current point ``p`` and its
reference counterpart ``q``. Scan-to-scan odometry composes these motions.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from laser_odom.core import se2
from laser_odom.core.parameters import param
from laser_odom.core.scan.laser_scan import ScanPoints

MAP_HEADING_WALK = 1.0e-5
"""Heading variance [rad^2/m] the integrated pose gains per metre against the local
map: about a twentieth of the scan-to-scan walk (``covariance_heading_walk``), which
left the whole-log NEES of map mode at 0.2-0.8 on fr079, MIT CSAIL and Intel (too
pessimistic: the map's revisited walls hold the heading the scan-to-scan steps lose);
1.8e-5 gave 0.5-3.7 over plicp, nicp and imls on the three logs, this value about
1.8x that where the walk dominates."""


@dataclass
class MatcherConfig:
    """Settings every matcher shares; each matcher subclasses it with tuned defaults."""

    max_iterations: int = param(
        30, 'Iteration cap of one match.', 1, 500)
    max_correspondence_distance: float = param(
        0.5, 'Pairs farther apart than this [m] are not correspondences.', 0.01, 10.0)
    convergence_translation: float = param(
        1e-5, 'Converged when an iteration moves the pose less than this [m]...', 0.0, 1.0)
    convergence_rotation: float = param(
        1e-5, '...and rotates it less than this [rad].', 0.0, 1.0)
    min_correspondences: int = param(
        10, 'A match with fewer correspondences than this fails.', 3, 100000)
    covariance_scale: float = param(
        1.0, 'Factor on the match covariance from the residuals (inflation calibrated so '
        'that the normalised estimation error squared on simulated runs is about 3).',
        0.01, 1000.0)
    covariance_shared_scan: float = param(
        0.0, 'Share of the match covariance that is the noise of one scan: consecutive '
        'scan-to-scan matches share a scan, so their errors partly cancel in the '
        'integrated pose (calibrated per matcher on simulated runs).', 0.0, 1.0)
    covariance_bias: float = param(
        0.0, 'Share of the rest that is a bias correlated over many steps: it adds up '
        'linearly in the integrated pose (calibrated per matcher).', 0.0, 1.0)
    covariance_bias_correlation: float = param(
        0.0, 'Correlation of that bias between consecutive steps (0.98: some 50 steps).',
        0.0, 0.999)
    covariance_baseline_falloff: float = param(
        0.0, 'A match n scans after its keyframe: the part of its covariance that is not '
        'noise of the two scans (white and bias) shrinks to (1 - covariance_shared_scan) / '
        'n^falloff and the noise of the scans takes the rest (icp: 1, its pairing errors '
        'fade as the scans move apart; plicp: 0.5, its lines are fitted to 0.2 m of surface; '
        'nicp, imls: 0, a surface model errs alike).',
        0.0, 3.0)
    covariance_heading_walk: float = param(
        1.8e-4, 'Heading variance [rad^2] the integrated pose gains per metre travelled '
        'from what a real scanner gets wrong for many steps (range and angle calibration, '
        'mixed pixels, reflections): 1.8e-4 (0.77 deg per square-root metre) fits the '
        'real logs; a simulated scanner has none of it (0).', 0.0, 1.0)
    map_covariance_heading_walk: float = param(
        MAP_HEADING_WALK, 'reference: local_map - the heading walk [rad^2 per metre] of the '
        'integrated pose when matching against the map: the map holds the heading a '
        'scan-to-scan match would lose, so it walks less than covariance_heading_walk; '
        'fitted to the real logs in map mode (0 for a simulated scanner).', 0.0, 1.0)
    map_surface_refine: bool = param(
        False, "reference: local_map - refine a clean match against the map's view once "
        "more on the map's own cell surfaces (no view in between; on for plicp, nicp and "
        'imls, whose ATE it lowers on every real log).')
    map_surface_weak_share: float = param(
        0.0, "reference: local_map - with map_surface_refine, a direction the map's cells "
        'measure with less than this share of the paired points (a point on a wall square '
        "to it adds one) keeps the matcher's pose: along a corridor the map's few features "
        'may lag where its scans joined (0 = correct every direction; nicp 0.05).',
        0.0, 1.0)
    map_surprise_check: bool = param(
        True, 'reference: local_map - check a clean map match that corrected a good '
        'prediction by far more than the recent misses against the previous scan, and take '
        'the step that fits both better when they disagree (off for icp: its point-to-point '
        "pairs bias the previous scan's match, fr079 map ATE 0.42 -> 0.55 m with it).")
    map_covariance_scale: float = param(
        1.6, 'reference: local_map - further factor on the covariance of a match against the '
        "map (the view's surfaces are averages, not one scan's points; calibrated per matcher "
        'on simulated runs).', 0.01, 1000.0)
    map_covariance_shared: float = param(
        0.9997, "reference: local_map - share of a map match's covariance that is the error "
        'of the map itself: consecutive matches against the map share it, so it does not add '
        'up; the rest adds up as white noise.', 0.0, 1.0)


@dataclass
class MatchResult:
    """Outcome of one scan match.

    ``pose`` is the current scan's pose in the reference frame. ``information`` is the
    3x3 information matrix of that estimate (``[x, y, theta]``, SI units) and
    ``covariance`` its inverse (regularised if the information is singular).
    ``residual`` is the RMS of the inlier residuals [m] under the matcher's metric.
    """

    pose: np.ndarray
    converged: bool
    iterations: int
    inlier_ratio: float
    residual: float
    information: np.ndarray
    covariance: np.ndarray
    correspondences: int = 0
    degenerate: bool = False
    extra: dict = field(default_factory=dict)

    @classmethod
    def failure(cls, initial_guess: np.ndarray, iterations: int = 0,
                correspondences: int = 0, reason: str = '') -> 'MatchResult':
        """Return a non-converged result that keeps the initial guess."""
        return cls(
            pose=np.array(initial_guess, dtype=float), converged=False,
            iterations=iterations, inlier_ratio=0.0, residual=float('inf'),
            information=np.zeros((3, 3)), covariance=np.diag([1e3, 1e3, 1e3]),
            correspondences=correspondences, extra={'reason': reason} if reason else {})


class ScanMatcher(ABC):
    """Base class of all matchers: a name, a configuration type and ``match``."""

    name: ClassVar[str]
    config_type: ClassVar[type[MatcherConfig]] = MatcherConfig

    def __init__(self, config: MatcherConfig | None = None) -> None:
        """Create the matcher with ``config`` or its tuned defaults."""
        self.config = config if config is not None else self.config_type()

    @abstractmethod
    def match(self, reference: ScanPoints, current: ScanPoints,
              initial_guess: se2.Pose) -> MatchResult:
        """Estimate the pose of ``current`` in the frame of ``reference``."""

    def match_from_prediction(self, reference: ScanPoints, current: ScanPoints,
                              prediction: se2.Pose) -> MatchResult:
        """Refine a trusted ``prediction``: the motion left to find is small.

        The default is :meth:`match`; a matcher with a wide first stage for far guesses
        (nicp's capture stage) leaves it out here.
        """
        return self.match(reference, current, prediction)

    def prepare_reference(self, scan: ScanPoints) -> None:
        """Build, in ``scan``'s cache, what only matching *against* it needs.

        Work a scan needs as the current one is done by :meth:`match`; what it needs
        only as the reference (a keyframe) can wait until the result of its own match
        is out, so the pipeline leaves it to this call, made after publishing
        (:meth:`.OdometryPipeline.prepare_next`). Skipped, ``match`` builds the same on
        demand, so results never depend on it. The default has nothing to prepare.
        """
