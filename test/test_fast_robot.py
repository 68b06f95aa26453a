"""A fast robot: the constant-velocity prediction is a guess, and a wrong one is not silent.

Issue 38 ("Unseen places and fast robots"). Scans 0.1 s apart of a robot covering
0.5-1 m between them: the prediction is trusted, and a wrong one led the match into a
wrong minimum that was judged clean. Now a prediction as large as the correction gate,
or after predictions that missed, is only a hypothesis: its match competes with the
global search's (:mod:`laser_odom.core.registration.doubt`).

The simulated test needs no data: a robot at 6 m/s in a corridor stops, or steps aside,
within one scan. The real-log test re-stamps every 5th/10th scan of fr079 and intel's
keyframes 0.1 s apart (skipped without ../shared/data) and runs them scan to scan and
against the local map with the default prior, and the same scans as recorded with
``prior: none`` both ways: issue 38's bars and issue 37's "never worse than scan mode"
from the same four runs, and the large steps without a prior (issue 28).
"""

import math

import numpy as np
import pytest

from laser_odom.core import se2
from laser_odom.core.configuration.pipeline import PipelineConfig
from laser_odom.core.datasets.variants import as_received
from laser_odom.core.evaluation.benchmark import benchmark_run, REAL_REFERENCE_NOISE
from laser_odom.core.evaluation.consistency import ANNOUNCED_NEES
from laser_odom.core.events import EventLog
from laser_odom.core.pipeline.odometry import OdometryPipeline
from laser_odom.core.simulation import get_world, LaserModel, render_scan
from laser_odom.core.uncertainty.pose_uncertainty import nees

CRUISE = se2.pose(0.6, 0.0, 0.0)
"""6 m/s at 10 Hz, along the corridor."""

SURPRISES = {'stop': se2.pose(0.0, 0.0, 0.0), 'side': se2.pose(0.0, 0.3, 0.0)}
"""What the robot does instead of the predicted step."""


def surprise_step(matcher: str, surprise: np.ndarray, seed: int = 3,
                  cruise: np.ndarray = CRUISE):
    """Drive six scans at ``cruise`` down a corridor, then ``surprise``.

    Return the last step's error, its estimate and the pipeline.
    """
    world = get_world('corridor')
    rng = np.random.default_rng(seed)
    poses = [world.path.poses_at(np.array([30.0]))[0]]
    for _ in range(6):
        poses.append(se2.compose(poses[-1], cruise))
    poses.append(se2.compose(poses[-1], surprise))
    pipeline = OdometryPipeline(PipelineConfig(matcher=matcher),
                                events=EventLog(lambda message: None))
    estimates = [pipeline.process(render_scan(world, pose, LaserModel(), rng,
                                              1_000_000_000 + k * 100_000_000))
                 for k, pose in enumerate(poses)]
    error = se2.relative(estimates[-2].pose, estimates[-1].pose) - surprise
    error[2] = se2.wrap_angle(error[2])
    return error, estimates[-1], pipeline


@pytest.mark.parametrize('matcher', ['plicp', 'nicp', 'imls'])
def test_a_fast_robot_that_stops_is_found(matcher):
    """Find where the robot stopped, though 0.6 m was predicted.

    Before, the match from the prediction slid along the corridor (plicp 0.62 m off,
    NEES 670: silent); now the search finds the step.
    """
    error, estimate, pipeline = surprise_step(matcher, SURPRISES['stop'])
    assert np.hypot(error[0], error[1]) < 0.03, (error, estimate.status)
    assert abs(error[2]) < math.radians(0.5), error
    assert pipeline.counters['search_doubtful'] >= 1


@pytest.mark.parametrize('matcher', ['plicp', 'nicp', 'imls'])
def test_a_fast_robot_that_steps_aside_is_found_or_announced(matcher):
    """Find a sidestep, or announce it with a covariance that covers the error.

    Before, plicp took a 0.6 m wrong step with a covariance of millimetres (NEES 3606).
    """
    error, estimate, _ = surprise_step(matcher, SURPRISES['side'])
    found = np.hypot(error[0], error[1]) < 0.03 and abs(error[2]) < math.radians(0.5)
    announced = nees(error, estimate.step_covariance) <= ANNOUNCED_NEES
    assert found or announced, (error, estimate.status, estimate.step_covariance)


@pytest.mark.parametrize('matcher', ['plicp', 'nicp', 'imls'])
def test_a_match_that_corrects_a_good_prediction_far_is_checked_by_the_search(matcher):
    """A robot at 1 m/s that jumps to 4 m/s: the match corrects the prediction by 0.3 m.

    The prediction is small and its record good (misses of millimetres), so it is not
    in doubt; the correction, 15 times the usual miss, is a surprise
    (:meth:`.doubt.PredictionDoubt.would_surprise`), and the search checks the match.
    Before, such a match was taken unchecked, however far it slid.
    """
    from laser_odom.core.registration.doubt import MIN_RECORD

    error, estimate, pipeline = surprise_step(matcher, se2.pose(0.4, 0.0, 0.0),
                                              cruise=se2.pose(0.1, 0.0, 0.0))
    # The first MIN_RECORD predictions were checked for their short record; the
    # surprise is the one search more.
    assert pipeline.counters['search_doubtful'] == MIN_RECORD + 1
    assert np.hypot(error[0], error[1]) < 0.03, (error, estimate.status)
    assert abs(error[2]) < math.radians(0.5), error


def test_a_correction_far_beyond_the_recent_misses_surprises_before_it_is_recorded():
    from laser_odom.core.registration.doubt import MIN_RECORD, PredictionDoubt

    doubt = PredictionDoubt()
    step = se2.pose(0.2, 0.0, 0.05)
    for _ in range(MIN_RECORD - 1):
        doubt.record(step, se2.compose(step, se2.pose(0.01, 0.0, 0.0)))
    far = se2.compose(step, se2.pose(0.3, 0.0, 0.0))
    assert doubt.would_surprise(step, far) == ''  # too short a record to judge
    doubt.record(step, se2.compose(step, se2.pose(0.03, 0.0, 0.0)))
    assert doubt.would_surprise(step, se2.compose(step, se2.pose(0.08, 0.0, 0.0))) == ''
    assert '0.30 m' in doubt.would_surprise(step, far)  # 10x the largest miss (0.03 m)
    turned = se2.compose(step, se2.pose(0.0, 0.0, 0.07))  # 3.5x the 0.02 rad floor
    assert '4.0 deg' in doubt.would_surprise(step, turned)
    assert len(list(doubt._misses)) == MIN_RECORD  # asking records nothing


def test_a_match_that_slid_beyond_the_gate_keeps_the_next_predictions_in_doubt():
    from laser_odom.core.configuration.pipeline import AcceptanceConfig
    from laser_odom.core.registration.doubt import MIN_RECORD, PredictionDoubt, RECENT_MISSES

    config = AcceptanceConfig()
    doubt = PredictionDoubt()
    step = se2.pose(0.2, 0.0, 0.0)
    near = se2.compose(step, se2.pose(0.01, 0.0, 0.0))
    for _ in range(MIN_RECORD):
        doubt.record(step, near)
    assert doubt.doubt(step, config) == ''
    # The match from the prediction slid 0.6 m; the search found the step 1 cm from it.
    doubt.record(step, near, local_failure='large_correction')
    for _ in range(RECENT_MISSES):
        assert 'slid' in doubt.doubt(step, config)
        doubt.record(step, near)
    assert doubt.doubt(step, config) == ''  # ten predictions since held
    doubt.record(step, near, local_failure='few_inliers')  # not a slide
    assert doubt.doubt(step, config) == ''


def fast_hall_run(seed: int, copy: int, config: PipelineConfig | None = None):
    """Return plicp's scan-to-scan row on a 1 mm noise copy of the simulated fast hall.

    The default prior, as a bag delivers the scans (float32), scored without reference
    noise (the simulation's poses are exact).
    """
    from laser_odom.core.datasets.variants import with_range_noise
    from laser_odom.core.evaluation.benchmark import GRIDS
    from laser_odom.core.evaluation.consistency import NO_REFERENCE_NOISE

    name = f'sim-hall-fast-s{seed}'
    scans = as_received(with_range_noise(GRIDS['worlds'][name].generate(name), copy, 0.001))
    return benchmark_run(scans, 'plicp', 'constant_velocity', config=config,
                         reference_noise=NO_REFERENCE_NOISE)


def test_a_slide_along_the_hall_aisle_after_a_slid_match_is_announced():
    """The simulated fast hall, plicp scan to scan, seed 1, copy 9 (issue 38).

    At scan 313 the match from the prediction slid beyond the correction gate and the
    search found the step 2 cm from the prediction. At scan 314 the match from as
    good a prediction slid 0.25 m back along the aisle, within the gate, and was taken
    as ``matched``; de-skewed with its own motion and matched again it slid to 0.65 m
    off, published with a 2 cm deviation, and the constant velocity carried it on over
    four more steps: 5 silent failed steps. Now the predictions after a slide are
    checked by the search, which finds the aisle weakly constrained: the same 5 steps
    fail, announced.
    """
    row = fast_hall_run(1, 9)
    assert row.steps >= 590 and row.failed <= 6, row
    assert row.silent == 0, row


def test_a_hall_alias_carried_on_by_the_prediction_is_announced():
    """The simulated fast hall, plicp scan to scan, seed 2, copy 3 (issue 38).

    Scan 123 took an alias 1.5 m along the aisle of pillars (announced). The constant
    velocity repeated it, and scan 124's degenerate match, picked among aliases nearest
    that prediction, was published with a centimetre across the aisle: NEES 165,
    silent. Now the step the prediction repeats stays out of the measured prediction
    error, and the prediction carries its covariance, which the next step covers.
    Since a searched step keeps its measured turn, the alias runs on for 10 failed
    steps instead of 3 (at scan 126 the search's grid, 2 cm off, refined no peak to
    the right pose), every one announced.
    """
    row = fast_hall_run(2, 3)
    assert row.steps >= 590 and 1 <= row.failed <= 12, row
    assert row.silent == 0, row


def test_weighed_velocity_keeps_a_step_the_hall_hardly_measured_from_the_prediction():
    """The simulated fast hall, plicp scan to scan, seed 3, copy 2 (issue 38).

    Along the aisle of pillars a run of weakly constrained steps (searched poses
    announced with 0.5-2 m of deviation) each replaced the constant velocity: it
    reached -0.66 m per step against the true +0.2, and ambiguous steps that keep the
    prediction's velocity carried it on: 24 failed steps, all announced (4 % of the
    599). With ``velocity_update: weighed`` such a step corrects the prediction by
    what the scans measured, weighed by the two errors
    (:func:`.motion.model.fused_with_prediction`): 4 failed. The default
    (``replace``) is held to its count too, so that a change to either shows.
    """
    from laser_odom.core.matchers import default_config

    rows = {}
    for update in ('replace', 'weighed'):
        config = PipelineConfig(matcher='plicp', matcher_config=default_config('plicp'))
        config.motion.velocity_update = update
        rows[update] = fast_hall_run(3, 2, config)
    weighed, replaced = rows['weighed'], rows['replace']
    assert weighed.steps >= 590 and weighed.failed <= 6, weighed
    assert weighed.silent == 0 and replaced.silent == 0, rows
    assert replaced.failed >= 15, replaced


FAST_LOGS = {'fr079/5-fast': 'fr079/5', 'fr079/10-fast': 'fr079/10',
             'intel-kf-fast': 'intel-kf'}
"""Each fast-robot log, and the same scans as recorded (0.05-4 s apart)."""

FAILED_GAP = {('fr079/10-fast', 'imls'), ('intel-kf-fast', 'nicp')}
"""Where the default prior still fails 1-2 more steps than ``prior: none`` on the
as-received scans (all announced): steps of 0.5-1.5 m and up to 90 deg in 0.1 s, where
the search from the prediction and the one from rest choose differently among poses
that fit poorly (surface fit 0.3-0.4, a coin flip either way). Open: issue 38 asks for
none. plicp left it when its segment lines took their surface's direction
(fr079/10-fast 7 -> 4 failed steps against 5 with no prior, intel-kf-fast 15 -> 8
against 11); nicp on fr079 every 5th and 10th scan when a searched match kept its turn
where the prediction stands in (:func:`.acceptance.judge_match`: 1 -> 0 against 0,
10 -> 7 against 8)."""

FAILED_BEFORE = {
    'intel-kf': {'plicp': 17, 'nicp': 11, 'imls': 11},
    'fr079/5': {'plicp': 0, 'nicp': 1, 'imls': 1},
    'fr079/10': {'plicp': 6, 'nicp': 8, 'imls': 7},
}
"""Failed steps as recorded with ``prior: none`` before the search window adapted
(c7b0fbe, the in-memory logs): none may fail more now (as a bag delivers them,
2026-12-08: intel-kf 9 / 3 / 6, fr079/5 0 / 0 / 1, fr079/10 5 / 8 / 7)."""

ROTATION_BAR = {'intel-kf': 1.0}
"""Mean rotational RPE [deg] allowed as recorded with ``prior: none``."""

FAST_ATE_RATIO = 1.1
"""Issue 37: map mode's ATE is at most this multiple of scan mode's on the same scans
with the same prior."""

FAST_SHORT: dict[tuple[str, str], dict[str, str]] = {
    ('nicp', 'intel-kf-fast'): {
        'ATE': '0.88 against 0.80 m (1.10x; the same 4 failed steps) since nicp is refined on '
               "the map's surfaces (map_surface_refine, map_surface_weak_share 0.05), which "
               'full-rate Intel drifts 0.56 -> 0.40 % with; 0.84 m with a share of 0.1 (fr079 '
               'at full rate then drifts 0.36 -> 0.45 %, 10 copies), 0.75 m with 0.2 (MIT CSAIL '
               'ATE 0.42 -> 0.54 m; nicp.matcher.NICP_MAP_WEAK_SHARE)'},
}
"""On the fast-robot logs as received: where map mode does worse than scan mode (issue
37 is open on these; before, intel-kf-fast failed 26/17/29 steps in map mode against
21/8/12 in scan mode; nicp and imls on fr079/10-fast 11 and 10 (1 silent each) against
10 and 9, intel-kf-fast nicp 6 (1) against 5, until a map match that moved far from an
unproven prediction was checked by the search, map_judging.overshot_unproven; plicp on
fr079/10-fast had an ATE of 10.3 m against the map and 6.5 m scan to scan until its
segment lines took their surface's direction: 9.9 m in both)."""


@pytest.mark.parametrize('dataset', sorted(FAST_LOGS))
@pytest.mark.parametrize('matcher', ['plicp', 'nicp', 'imls'])
def test_fast_logs_have_no_silent_failure_and_the_map_is_no_worse(real_log, matcher, dataset):
    """Issues 37 and 38 on one log's scans, fast and as recorded, from four runs.

    Re-stamped 0.1 s apart with the default prior, scan to scan: no silent failed step,
    no more failed steps than the same scans as recorded with ``prior: none`` (before:
    intel-kf-fast 21/10, 8/5, 12/6 failed/silent; fr079/10-fast nicp 15/2). Against the
    local map, fast with the default prior and as recorded with ``prior: none``: no
    silent failed step either, and no more failed or silent steps than scan mode on the
    same scans with the same prior, with an ATE within :data:`FAST_ATE_RATIO` of it
    (before: intel-kf-fast map mode 30/6, 18/4, 19/2 failed/silent, scan 12/0, 4/0,
    5/0). As recorded with ``prior: none`` scan to scan, steps of 0.5-2 m and 10-170 deg
    (intel's keyframes 3-4 s apart, fr079 every 5th and 10th scan) hold
    :data:`FAILED_BEFORE` and :data:`ROTATION_BAR`.
    """
    recorded = FAST_LOGS[dataset]
    fast, slow = as_received(real_log(dataset)), as_received(real_log(recorded))
    rows = {(prior, reference): benchmark_run(scans, matcher, prior, reference=reference,
                                              reference_noise=REAL_REFERENCE_NOISE)
            for scans, prior in ((fast, 'constant_velocity'), (slow, 'none'))
            for reference in ('scan', 'local_map')}
    scan, none = rows['constant_velocity', 'scan'], rows['none', 'scan']
    mapped, none_mapped = rows['constant_velocity', 'local_map'], rows['none', 'local_map']
    figures = (f'{matcher} on {dataset}, failed (silent), ATE: scan {scan.failed} '
               f'({scan.silent}) of {scan.steps}, {scan.ate:.2f} m; map {mapped.failed} '
               f'({mapped.silent}), {mapped.ate:.2f} m; as recorded, prior none: scan '
               f'{none.failed} ({none.silent}), {none.ate:.2f} m, RPE {none.rpe_rot_mean:.3f} '
               f'deg; map {none_mapped.failed} ({none_mapped.silent}), {none_mapped.ate:.2f} m')
    assert min(row.steps for row in rows.values()) >= 470, figures
    assert mapped.reference == none_mapped.reference == 'local_map', figures
    assert scan.silent == mapped.silent == none.silent == none_mapped.silent == 0, figures
    if (dataset, matcher) in FAILED_GAP:  # strict: a fix shows
        assert scan.failed > none.failed, f'{figures} (a fix)'
    else:
        assert scan.failed <= none.failed, figures
    assert none.failed <= FAILED_BEFORE[recorded][matcher], figures
    assert none.rpe_rot_mean <= ROTATION_BAR.get(recorded, math.inf), figures
    assert none_mapped.failed <= none.failed, figures
    assert none_mapped.ate <= FAST_ATE_RATIO * none.ate, figures
    short = {'failed steps': mapped.failed > scan.failed,
             'silent': mapped.silent > scan.silent,
             'ATE': mapped.ate > FAST_ATE_RATIO * scan.ate}
    missed = {bar for bar, is_short in short.items() if is_short}
    known = set(FAST_SHORT.get((matcher, dataset), {}))
    assert missed == known, f'missed {sorted(missed)}, documented {sorted(known)}: {figures}'
