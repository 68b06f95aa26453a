"""Covariance of the integrated pose when the errors of consecutive matches are correlated.

Compounding each match's covariance as if its error were independent of the others
(``P' = Ja P Ja^T + Jb S Jb^T``, Smith, Self & Cheeseman 1990) is right only for
white step errors. Scan-to-scan errors are not white, for two reasons:

1. **Shared scans.** Steps k and k+1 share scan k. The error that scan's own noise puts
   into the alignment, ``n_k``, enters step k with one sign and step k+1 with the
   other: ``e_k = n_k - n_{k-1} + ...``. Consecutive step errors are then negatively
   correlated (-0.5 at lag 1 if that were all) and their sum telescopes, so the white
   model's variance, which grows linearly, is too pessimistic over a few steps.
2. **Bias.** Beam sampling, normal estimation and trimming err the same way for many
   steps in a row (along a corridor, the same walls). A bias shared by nearby steps
   adds up linearly, so over a hundred steps the white model is too confident.

The step error is therefore modelled, in the step's own frame, as
``e_k = (n_k - n_{k-1}) + w_k + b_k`` with ``n_k ~ N(0, a S_k / 2)`` (per scan,
shared), ``w_k ~ N(0, (1 - a - c) S_k)`` (white) and a first-order Gauss-Markov bias
``b_k = phi b_{k-1} + u_k`` with stationary covariance ``c S_k`` (``u_k ~ N(0, (1 -
phi^2) c S_k)``). The shares add up to one, so a single step's error keeps the
covariance ``S_k`` the matcher reports: ``2 (a/2) + (1 - a - c) + c = 1``. The state
``x = [dp, n, b]`` (pose error in the odom frame, the newest scan's noise, the bias)
is propagated with its 9x9 joint covariance:

``dp' = Ja dp + Jb (n' - n + w + phi b + u)``, ``n' = n_new``, ``b' = phi b + u``.

The shares ``a`` (``covariance_shared_scan``), ``c = covariance_bias * (1 - a)`` (a share
of what the shared part leaves, so every setting is valid) and ``phi``
(``covariance_bias_correlation``) are per matcher, calibrated on simulated runs so that
the NEES of relative poses over 1, 10 and 100 steps and of the whole run is about 3,
with keyframes off and on. Against a keyframe, every match shares the keyframe's scan:
each one is propagated from the keyframe's joint state, and only the transitions
between keyframes compound. Both settings constrain the bias: a bias that decorrelates
within a few dozen steps (``phi`` 0.95) fits runs scan to scan, but predicts keyframe
transitions (several scans apart, so a few dozen transitions span a whole run) to
wander more than they do; a small bias that persists (``phi`` 0.999: the same sign for
a thousand matches, as a systematic under- or overestimate of the motion would) fits
both.

**Baseline.** With keyframes a match spans ``n`` scans, and how its error splits
depends on what the matcher pairs. ``icp`` and ``plicp`` pair each point with the other
scan's samples; two scans a few centimetres apart sample the walls at nearly the same
spots, so the pairing errs alike from one step to the next (point to point, matched
noise-free from the true pose in the office world, pairs 1, 2, 4 and 7 scans apart err
by 1.56, 0.67, 0.23 and 0.11 mm^2 along the corridor and 45, 11, 4.1 and 3.9 mdeg^2 in
heading). Across a keyframe's 7 scans (0.3 m) that pairing error has faded: the
transitions of both are honest one by one (NEES 2.2-3.0 for ``plicp``), carry no
measurable mean error where scan-to-scan steps of ``icp`` err by 0.3 mm each the same
way, and telescope (lag-1 correlation -0.2 to -0.5), so that after 1000 scans the
heading of ``plicp`` errs by 0.03-0.16 deg where compounding them with the
scan-to-scan shares predicts 0.42-0.47 deg. So the part of a match's covariance that is
not the scans' own noise, white and bias, shrinks with the baseline to ``r_n = (1 - a)
/ n^gamma`` (``covariance_baseline_falloff`` ``gamma``); the scans' own noise takes the
rest, ``a_n = 1 - r_n``, and the bias its share of it, ``c_n = covariance_bias r_n``,
which keeps a single match's covariance ``S_k``. ``gamma`` 1 fits ``icp`` with keyframes
in both simulated worlds. ``nicp`` and ``imls`` fit a surface model (normals and
curvature, an implicit surface) to the noisy points, and its error does not fade with
the baseline: ``gamma`` 0. ``plicp``, whose segment lines are fitted to 0.2 m of surface
(``segment_window``), sits between: ``gamma`` 0.5. Scan to scan ``n`` is 1 and ``gamma``
changes nothing.
The pipeline applies the model to good matches only: the covariance of a degenerate or
rejected step is ignorance, not scan noise, and compounds as white.

**A real scanner's heading walk.** The shares above are calibrated on simulated runs,
where they give a whole-run NEES of 1.5-6. On the real logs (fr079, MIT CSAIL, Intel;
SICK scanners with 180 deg fields of view) the same model gave 14-78: the heading
drifts there by 0.07-0.18 deg per metre, in the same direction for all three matchers
on a log (fr079 -39 to -49 deg, Intel +17 to +29 deg over the log), which the
simulated scanner, with its exact ranges and beam angles, never shows (its 180 deg
runs drift by well under 0.02 deg/m). What differs is the sensor: range and angle
calibration, mixed pixels at edges and reflections that err alike for many scans.
It is modelled as a heading random walk per metre travelled, ``q d`` added to the
step's heading variance in its own frame (``covariance_heading_walk`` ``q`` [rad^2/m],
``d`` the step length), as wheel-odometry error models grow heading noise with
distance (Thrun, Burgard & Fox, "Probabilistic Robotics", 2005, Sec. 5.4). A rigid
bias per metre (the drift's sign kept for the whole log) fits the heading but not
the position errors its lever arms predict; the walk fits both. It is 0 for a
simulated scanner.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from laser_odom.core import se2

CHI2_3DOF_999 = 16.27
"""The 99.9 % quantile of chi-square with 3 dof: a pose error whose :func:`nees` against
a covariance is within it is covered by that covariance."""

POSE = slice(0, 3)
"""The pose block of the joint state; then the newest scan's noise (3:6) and the bias (6:9)."""


@dataclass(frozen=True)
class StepErrorModel:
    """How a matcher's step error splits: shared-scan noise, white part, correlated bias.

    ``shared_scan`` and ``bias_share`` are in [0, 1] (the declared ranges); the bias
    takes ``bias_share`` of what the shared part leaves, ``bias_correlation`` < 1; in a
    match ``n`` scans after its keyframe what the shared part leaves falls off as
    ``n^-baseline_falloff`` (module docstring, "Baseline").
    """

    shared_scan: float = 0.0
    bias_share: float = 0.0
    bias_correlation: float = 0.0
    baseline_falloff: float = 0.0
    heading_walk: float = 0.0
    """Heading variance [rad^2] per metre of a step (module docstring, "A real scanner's
    heading walk")."""

    @classmethod
    def of(cls, config: object) -> StepErrorModel:
        """Return the model a matcher configuration declares."""
        return cls(config.covariance_shared_scan, config.covariance_bias,
                   config.covariance_bias_correlation, config.covariance_baseline_falloff,
                   config.covariance_heading_walk)

    @classmethod
    def of_map(cls, config: object) -> StepErrorModel:
        """Return the model of matches against the local map a matcher configuration declares.

        Consecutive matches against the map share the map's error, which does not add
        up (``map_covariance_shared``); what the map does not share is white. A real
        scanner's heading walk errs the map along with the scans, so it stays, but
        slower than scan to scan (``map_covariance_heading_walk``: the map keeps the
        walls a revisit matches again).
        """
        return cls(config.map_covariance_shared,
                   heading_walk=config.map_covariance_heading_walk)

    def shares(self, scans_apart: int = 1) -> tuple[float, float]:
        """Return the shared-scan and bias shares of a match spanning ``scans_apart`` scans.

        What the shared part leaves, ``r = (1 - shared_scan) / n^baseline_falloff``, is
        split into bias (``bias_share * r``) and white; the shared part is ``1 - r``.
        """
        rest = (1.0 - self.shared_scan) / scans_apart ** self.baseline_falloff
        return 1.0 - rest, self.bias_share * rest


def step_error(status: str, covariance: np.ndarray, matcher_config: object,
               from_map: bool = False, doubt: np.ndarray | None = None
               ) -> tuple[np.ndarray, StepErrorModel]:
    """Return a judged match's step covariance and how its error compounds.

    Only a good (``matched``) match's error is noise that the next match cancels (the
    shared scan, or the map both match against); the covariance of a degenerate match
    (no information along a corridor) or of a rejected one (the prediction) is
    ignorance, which stays: those compound white. A match against the local map
    (``from_map``) has the matcher's ``map_covariance_scale`` and shares all but a
    white rest of its error with the next (:meth:`StepErrorModel.of_map`). A
    ``doubt`` (two references that disagreed on the step) is ignorance too: it is
    added, and the step compounds white.
    """
    if status == 'rejected':
        return covariance, StepErrorModel()
    if from_map:
        covariance = covariance * matcher_config.map_covariance_scale
    if doubt is not None:
        return covariance + doubt, StepErrorModel()
    if status != 'matched':
        return covariance, StepErrorModel()
    return covariance, (StepErrorModel.of_map(matcher_config) if from_map
                        else StepErrorModel.of(matcher_config))


@dataclass(frozen=True)
class PoseUncertainty:
    """Joint covariance (9x9) of the pose error, the newest scan's noise and the bias.

    ``scan_known`` tells whether the noise block belongs to a scan already matched
    (after a reset the reference scan's noise and the bias start from their prior).
    """

    joint: np.ndarray
    scan_known: bool = False

    @classmethod
    def at(cls, pose_covariance: np.ndarray | None = None) -> PoseUncertainty:
        """Return the state at a (re)start: the given pose covariance, nothing else known."""
        joint = np.zeros((9, 9))
        if pose_covariance is not None:
            joint[POSE, POSE] = pose_covariance
        return cls(joint)

    @property
    def pose_covariance(self) -> np.ndarray:
        """Covariance (3x3, ``[x, y, yaw]``) of the pose in the odom frame."""
        block = self.joint[POSE, POSE]
        return 0.5 * (block + block.T)

    def propagate(self, anchor: se2.Pose, step: se2.Pose, step_covariance: np.ndarray,
                  model: StepErrorModel, scans_apart: int = 1) -> PoseUncertainty:
        """Return the state after composing ``anchor`` with a matched ``step``.

        ``anchor`` is the pose this state describes (the keyframe's); ``step`` and
        ``step_covariance`` are the match's estimate and covariance ``S``;
        ``scans_apart`` is how many scans the match spans (1 scan to scan).
        """
        ja, jb = se2.compose_jacobians(anchor, step)
        shared, bias = model.shares(scans_apart)
        walk = model.heading_walk * float(np.hypot(step[0], step[1]))
        joint = _propagate(self.joint, self.scan_known, ja, jb,
                           np.ascontiguousarray(step_covariance, dtype=float),
                           shared, bias, model.bias_correlation, walk)
        return PoseUncertainty(joint, scan_known=True)


@numba.njit(cache=True, nogil=True)
def _propagate(joint: np.ndarray, scan_known: bool, ja: np.ndarray, jb: np.ndarray,
               step_covariance: np.ndarray, shared_scan: float, bias: float,
               phi: float, walk: float) -> np.ndarray:
    """Compiled :meth:`PoseUncertainty.propagate`: ``F C F^T + Q`` (module docstring).

    ``walk`` [rad^2] is the step's heading walk, white in the step's frame.
    """
    shared = 0.5 * shared_scan * step_covariance
    white = max(0.0, 1.0 - shared_scan - bias) * step_covariance
    innovation = (1.0 - phi * phi) * bias * step_covariance
    joint = joint.copy()
    if not scan_known:  # the reference scan's noise and the bias: their priors
        joint[3:9, :] = 0.0
        joint[:, 3:9] = 0.0
        joint[3:6, 3:6] = shared
        joint[6:9, 6:9] = bias * step_covariance
    transition = np.zeros((9, 9))
    transition[0:3, 0:3] = ja
    transition[0:3, 3:6] = -jb
    transition[0:3, 6:9] = phi * jb
    transition[6:9, 6:9] = phi * np.eye(3)
    noise = np.zeros((9, 9))
    own = shared + white + innovation
    own[2, 2] += walk
    noise[0:3, 0:3] = jb @ own @ jb.T
    noise[0:3, 3:6] = jb @ shared
    noise[3:6, 0:3] = shared @ jb.T
    noise[3:6, 3:6] = shared
    noise[0:3, 6:9] = jb @ innovation
    noise[6:9, 0:3] = innovation @ jb.T
    noise[6:9, 6:9] = innovation
    joint = transition @ joint @ transition.T + noise
    return 0.5 * (joint + joint.T)


def nees(error: np.ndarray, covariance: np.ndarray) -> float:
    """Return ``e^T P^-1 e`` with the angle of ``e`` wrapped to (-pi, pi]."""
    error = np.array(error, dtype=float)
    error[2] = se2.wrap_angle(error[2])
    return float(error @ np.linalg.solve(covariance, error))
