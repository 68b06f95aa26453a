"""The odometry pipeline: prediction, integration, stamps, keyframes, acceptance."""

import math

import numpy as np
import pytest

from laser_odom.core import se2
from laser_odom.core.configuration.pipeline import PipelineConfig
from laser_odom.core.evaluation.metrics import evaluate
from laser_odom.core.pipeline.odometry import OdometryPipeline
from laser_odom.core.pipeline.runner import run_pipeline
from laser_odom.core.scan.laser_scan import LaserScan
from laser_odom.core.simulation import simulate


@pytest.fixture(scope='module')
def office_run():
    """Twenty seconds in the office world: 200 scans with ground truth."""
    return simulate('office', duration=20.0, seed=3)


def replace_stamp(scan: LaserScan, stamp_ns: int) -> LaserScan:
    return LaserScan(stamp_ns, scan.angle_min, scan.angle_max, scan.angle_increment,
                     scan.range_min, scan.range_max, scan.ranges, scan.intensities,
                     scan.frame_id)


def test_tracks_ground_truth_and_reports_finite_spd_covariance(office_run):
    pipeline = OdometryPipeline(PipelineConfig(matcher='icp'))
    result = run_pipeline(pipeline, office_run.scans)
    assert result.processed == len(office_run.scans)
    errors = evaluate(result.trajectory, office_run.reference)
    assert errors.ate_rms < 0.08  # icp underestimates office steps by ~0.3 mm: 4-6 cm in 20 s
    assert errors.rpe_trans_mean < 0.005
    for covariance in result.pose_covariances[1:]:
        assert np.all(np.isfinite(covariance))
        assert np.allclose(covariance, covariance.T)
        assert np.all(np.linalg.eigvalsh(covariance) > 0.0)
    # Pose uncertainty grows as the odometry integrates.
    assert np.trace(result.pose_covariances[-1]) > np.trace(result.pose_covariances[10])


def test_twist_is_in_the_base_frame(office_run):
    pipeline = OdometryPipeline(PipelineConfig(matcher='icp'))
    estimates = [pipeline.process(scan) for scan in office_run.scans[:30]]
    truth = office_run.reference.poses
    dt = (office_run.scans[29].stamp_ns - office_run.scans[28].stamp_ns) * 1e-9
    expected = se2.relative(truth[28], truth[29]) / dt
    assert np.allclose(estimates[29].twist, expected, atol=0.05)
    assert estimates[29].twist_covariance.shape == (3, 3)


def test_constant_velocity_prediction_is_the_initial_guess(office_run):
    pipeline = OdometryPipeline(PipelineConfig(matcher='icp'))
    for scan in office_run.scans[:10]:
        pipeline.process(scan)
    velocity = pipeline.motion.velocity
    assert np.allclose(pipeline.motion.predict(0.1), velocity * 0.1)
    none = OdometryPipeline(PipelineConfig(matcher='icp'))
    none.config.motion.prior = 'none'
    assert np.allclose(none.motion.predict(0.1), 0.0)


def test_duplicate_stamp_is_skipped_and_time_jump_back_resets(office_run):
    pipeline = OdometryPipeline(PipelineConfig(matcher='icp'))
    scans = office_run.scans
    for scan in scans[:20]:
        pipeline.process(scan)
    assert pipeline.process(scans[19]) is None
    assert pipeline.counters['duplicate_stamp'] == 1
    moved = pipeline.pose.copy()
    assert np.hypot(moved[0], moved[1]) > 0.2
    restarted = pipeline.process(scans[0])
    assert restarted.status == 'initialized'
    assert pipeline.counters['time_jump_back'] == 1
    assert np.allclose(restarted.pose, 0.0)


def test_scan_gap_drops_the_prior(office_run):
    pipeline = OdometryPipeline(PipelineConfig(matcher='icp'))
    for scan in office_run.scans[:10]:
        pipeline.process(scan)
    late = replace_stamp(office_run.scans[10], office_run.scans[9].stamp_ns + int(5e9))
    pipeline.process(late)
    assert pipeline.counters['scan_gap'] == 1


def test_keyframes_hold_the_reference_while_the_robot_stands_still(office_run):
    config = PipelineConfig(matcher='icp')
    config.keyframes.keyframe_distance = 0.5
    config.keyframes.keyframe_angle = math.radians(20.0)
    pipeline = OdometryPipeline(config)
    first = office_run.scans[0]
    pipeline.process(first)
    keyframe = pipeline.keyframe
    rng = np.random.default_rng(0)
    for k in range(1, 50):
        ranges = first.ranges + rng.normal(0.0, 0.01, first.ranges.shape)
        still = LaserScan(first.stamp_ns + k * 100_000_000, first.angle_min,
                          first.angle_max, first.angle_increment, first.range_min,
                          first.range_max, ranges)
        estimate = pipeline.process(still)
    assert pipeline.keyframe is keyframe
    # Matching against one keyframe does not random-walk: the error stays at one match's.
    assert np.hypot(*estimate.pose[:2]) < 0.005


def test_rejected_match_advances_by_the_prediction(office_run):
    config = PipelineConfig(matcher='icp')
    config.acceptance.max_correction_linear = 1e-9  # no match lands exactly on the guess
    config.search.global_search = 'off'  # nothing checks the match again
    pipeline = OdometryPipeline(config)
    pipeline.process(office_run.scans[0])
    pipeline.motion.velocity = np.array([0.5, 0.0, 0.0])
    estimate = pipeline.process(office_run.scans[1])
    assert estimate.status == 'rejected'
    assert np.allclose(estimate.pose, [0.05, 0.0, 0.0])
    assert estimate.pose_covariance[0, 0] >= 0.25


def test_jittery_logger_stamps_use_the_mean_scan_interval():
    from laser_odom.core.configuration.pipeline import MotionConfig
    from laser_odom.core.motion.model import MotionModel
    model = MotionModel(MotionConfig())
    bursty = [0.01, 0.39] * 10  # a 5 Hz sensor logged in pairs
    for dt in bursty:
        model.update(np.array([0.1, 0.0, 0.05]), dt)
    assert abs(model.effective_dt(0.01) - 0.2) < 1e-9
    assert np.allclose(model.predict(0.39), [0.1, 0.0, 0.05])
    regular = MotionModel(MotionConfig())
    for dt in [0.1] * 10 + [0.2]:  # true stamps with one dropped scan
        regular.update(np.array([0.05, 0.0, 0.0]), dt)
    assert regular.effective_dt(0.2) == 0.2
    assert regular.effective_dt(0.001) == 0.1  # a lone glitch is one period


@pytest.mark.parametrize('matcher', ['icp', 'plicp', 'nicp', 'imls'])
def test_reference_preparation_after_publishing_changes_no_result(office_run, matcher):
    """The node prepares the next keyframe after publishing; the result must not depend on it."""
    scans = office_run.scans[:40]
    prepared, lazy = (OdometryPipeline(PipelineConfig(matcher=matcher)) for _ in range(2))
    prepared_run = run_pipeline(prepared, scans)  # prepares after every scan
    lazy_poses = []
    for scan in scans:
        estimate = lazy.process(scan)
        lazy_poses.append(estimate.pose)
        assert not lazy.keyframe_prepared
    np.testing.assert_array_equal(prepared_run.trajectory.poses, np.array(lazy_poses))
    assert prepared.keyframe_prepared


def test_icp_reference_work_moves_off_the_matching_path(office_run):
    """The densified reference and information normals of icp are built by prepare_next."""
    pipeline = OdometryPipeline(PipelineConfig(matcher='icp'))
    pipeline.process(office_run.scans[0])
    keyframe = pipeline.keyframe
    assert not any(key[0] in ('icp_dense', 'normals') for key in keyframe.cache)
    assert pipeline.prepare_next() > 0.0
    assert {key[0] for key in keyframe.cache} >= {'icp_dense', 'normals'}
    assert pipeline.prepare_next() == 0.0  # once per keyframe
    times = len(pipeline.processing_times)
    pipeline.process(office_run.scans[1])
    assert pipeline.keyframe is not keyframe and not pipeline.keyframe_prepared
    assert len(pipeline.processing_times) == times + 1


def test_counters_count_each_outcome_once(office_run):
    """scans_in counts every scan, processed the non-skipped, and each status its own."""
    pipeline = OdometryPipeline(PipelineConfig(matcher='icp'))
    scans = office_run.scans
    for scan in scans[:12] + [scans[11]]:  # the last one repeats a stamp: skipped
        pipeline.process(scan)
    counters = pipeline.counters
    assert counters['scans_in'] == 13 and counters['processed'] == 12
    assert counters['initialized'] == 1 and counters['matched'] == 11
    assert counters['duplicate_stamp'] == 1
    assert len(pipeline.processing_times) == 12


def test_skips_and_gaps_are_said_with_the_scans_stamp(office_run):
    """The duplicate-stamp and scan-gap messages name the stamp in seconds."""
    from laser_odom.core.events import EventLog
    said = []
    pipeline = OdometryPipeline(PipelineConfig(matcher='icp'), events=EventLog(said.append))
    scans = office_run.scans
    for scan in scans[:3] + [scans[2]]:
        pipeline.process(scan)
    late = replace_stamp(scans[3], scans[2].stamp_ns + 2_500_000_000)
    pipeline.process(late)
    t2, t3 = scans[2].stamp_ns * 1e-9, late.stamp_ns * 1e-9
    assert said[0] == f'scan at t={t2:.3f} skipped: same stamp as the previous scan'
    assert said[1].startswith(f'2.50 s between the scans before t={t3:.3f}, longer than '
                              'max_scan_gap (1 s)')


def test_velocity_and_trust_follow_the_last_match(office_run):
    """After a match the velocity is the matched step over dt and the prediction trusted."""
    pipeline = OdometryPipeline(PipelineConfig(matcher='icp'))
    estimates = [pipeline.process(scan) for scan in office_run.scans[:15]]
    truth = office_run.reference.poses
    assert estimates[-1].status == 'matched' and pipeline.untrusted == ''
    step = se2.relative(estimates[-2].pose, estimates[-1].pose)
    np.testing.assert_allclose(pipeline.motion.velocity, step / 0.1, rtol=1e-9)
    # One match is good to a few millimetres: the velocity to a few cm/s.
    np.testing.assert_allclose(pipeline.motion.velocity,
                               se2.relative(truth[13], truth[14]) / 0.1, atol=0.06)


def test_twist_covariance_is_the_step_covariance_over_dt_squared(office_run):
    """The twist is the step over dt and its covariance the step's over dt^2."""
    pipeline = OdometryPipeline(PipelineConfig(matcher='icp'))
    previous = pipeline.process(office_run.scans[0])
    assert previous.step_covariance is None
    for scan in office_run.scans[1:6]:
        estimate = pipeline.process(scan)
        step = se2.relative(previous.pose, estimate.pose)
        np.testing.assert_allclose(estimate.twist, step / 0.1, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(estimate.twist_covariance,
                                   estimate.step_covariance / 0.01, rtol=1e-9)
        assert np.all(np.diag(estimate.step_covariance) > 0.0)
        previous = estimate


def test_pose_covariance_compounds_the_matchers_error_model(office_run):
    """Matched steps compound with the matcher's declared shares (plicp: shared scan, bias).

    The pose covariance is the propagation of each step's covariance from the previous
    pose, with StepErrorModel.of(matcher config) for a matched step.
    """
    from laser_odom.core.uncertainty.pose_uncertainty import PoseUncertainty, StepErrorModel
    pipeline = OdometryPipeline(PipelineConfig(matcher='plicp'))
    model = StepErrorModel.of(pipeline.matcher.config)
    assert model.shared_scan > 0.0 and model.bias_share > 0.0
    previous = pipeline.process(office_run.scans[0])
    expected = PoseUncertainty.at(np.zeros((3, 3)))
    white = PoseUncertainty.at(np.zeros((3, 3)))
    for scan in office_run.scans[1:8]:
        estimate = pipeline.process(scan)
        assert estimate.status == 'matched'
        step = se2.relative(previous.pose, estimate.pose)
        expected = expected.propagate(previous.pose, step, estimate.step_covariance, model)
        white = white.propagate(previous.pose, step, estimate.step_covariance,
                                StepErrorModel())
        np.testing.assert_allclose(estimate.pose_covariance, expected.pose_covariance,
                                   rtol=1e-9, atol=1e-15)
        previous = estimate
    assert not np.allclose(expected.pose_covariance, white.pose_covariance, rtol=0.05)


def test_first_scan_is_the_reference_at_rest():
    """An initialized estimate: the start pose, its covariance, and a twist not yet known.

    Nothing has been matched, so the zero twist is a placeholder: its variance says
    "unknown" (1e3, robot_localization's largest without a warning), not 1e-6.
    """
    scans = simulate('office', duration=0.3, seed=3).scans
    scan = scans[0]
    pipeline = OdometryPipeline(PipelineConfig(matcher='icp'))
    pipeline.reset(se2.pose(1.0, 2.0, 0.5), np.eye(3) * 0.01)
    estimate = pipeline.process(scan)
    assert estimate.status == 'initialized' and estimate.step_covariance is None
    np.testing.assert_array_equal(estimate.pose, [1.0, 2.0, 0.5])
    np.testing.assert_array_equal(estimate.pose_covariance, np.eye(3) * 0.01)
    np.testing.assert_array_equal(estimate.twist, np.zeros(3))
    np.testing.assert_array_equal(estimate.twist_covariance, np.eye(3) * 1e3)
    second = pipeline.process(scans[1])
    assert second.status == 'matched'
    assert np.all(np.diag(second.twist_covariance) < 1.0)  # measured: far below unknown


def test_processing_time_is_the_time_spent_in_process(office_run):
    """processing_time lies within the wall time of the call; prepare_next adds its own."""
    import time
    pipeline = OdometryPipeline(PipelineConfig(matcher='icp'))
    for scan in office_run.scans[:3]:
        pipeline.process(scan)
        pipeline.prepare_next()
    started = time.perf_counter()
    estimate = pipeline.process(office_run.scans[3])
    took = time.perf_counter() - started
    assert 0.0 < estimate.processing_time <= took
    assert pipeline.processing_times[-1] == estimate.processing_time
    started = time.perf_counter()
    prepared = pipeline.prepare_next()
    took = time.perf_counter() - started
    assert 0.0 < prepared <= took
    assert pipeline.processing_times[-1] == pytest.approx(
        estimate.processing_time + prepared, rel=1e-12)


def test_time_jump_back_is_said_with_both_stamps(office_run):
    """The reset on a stamp earlier than the last one says both stamps in seconds."""
    from laser_odom.core.events import EventLog
    said = []
    pipeline = OdometryPipeline(PipelineConfig(matcher='icp'), events=EventLog(said.append))
    scans = office_run.scans
    for scan in (scans[5], scans[6], scans[2]):
        pipeline.process(scan)
    t6, t2 = scans[6].stamp_ns * 1e-9, scans[2].stamp_ns * 1e-9
    assert said == [f'scan stamp t={t2:.3f} is earlier than the previous t={t6:.3f} (bag '
                    'loop or restarted clock): odometry reset to the origin']


@pytest.mark.parametrize('rejected_motion', ['predict', 'hold'])
def test_a_rejection_stops_the_robot_distrusts_the_prediction_and_says_what_it_did(
        office_run, rejected_motion):
    """After a rejection: velocity zero, prediction untrusted, the action said.

    The message names the stamp and whether the pose advanced by the prediction or held.
    """
    from laser_odom.core.events import EventLog
    said = []
    config = PipelineConfig(matcher='icp')
    config.search.global_search = 'off'
    config.acceptance.rejected_motion = rejected_motion
    pipeline = OdometryPipeline(config, events=EventLog(said.append))
    for scan in office_run.scans[:5]:
        pipeline.process(scan)
    velocity = pipeline.motion.velocity.copy()
    before = pipeline.pose.copy()
    pipeline.config.acceptance.max_correction_linear = 1e-9
    estimate = pipeline.process(office_run.scans[5])
    assert estimate.status == 'rejected'
    np.testing.assert_array_equal(pipeline.motion.velocity, np.zeros(3))
    assert pipeline.untrusted == 'rejected'
    assert pipeline.counters['rejected'] == 1
    assert pipeline.counters['rejected_large_correction'] == 1
    advance = velocity * 0.1 if rejected_motion == 'predict' else np.zeros(3)
    np.testing.assert_allclose(estimate.pose, se2.compose(before, advance), atol=1e-12)
    at = f't={office_run.scans[5].stamp_ns * 1e-9:.3f}'
    action = ('advancing by the prediction' if rejected_motion == 'predict'
              else 'holding the pose')
    assert said[-1].startswith(f'match at {at} rejected (')
    assert said[-1].endswith(f'; {action}')
    # The scan is the new reference: the next match is against it, from rest.
    assert pipeline.keyframe.stamp_ns == office_run.scans[5].stamp_ns


def test_a_rejection_with_no_prior_says_it_holds_the_pose(office_run):
    """With prior none there is no prediction to advance by; the message says so."""
    from laser_odom.core.events import EventLog
    said = []
    config = PipelineConfig(matcher='icp')
    config.motion.prior = 'none'
    config.search.global_search = 'off'
    config.acceptance.max_correction_linear = 1e-9
    pipeline = OdometryPipeline(config, events=EventLog(said.append))
    for scan in office_run.scans[:2]:
        estimate = pipeline.process(scan)
    assert estimate.status == 'rejected'
    assert said[-1].endswith('; holding the pose (prior none: no prediction to advance by)')


def test_a_rejected_step_compounds_white_whatever_the_matchers_shares(office_run):
    """A rejected step's covariance is ignorance: propagated with the white model."""
    from laser_odom.core.uncertainty.pose_uncertainty import PoseUncertainty, StepErrorModel
    config = PipelineConfig(matcher='plicp')
    config.search.global_search = 'off'
    pipeline = OdometryPipeline(config)
    model = StepErrorModel.of(pipeline.matcher.config)
    estimates = [pipeline.process(scan) for scan in office_run.scans[:3]]
    expected = PoseUncertainty.at(np.zeros((3, 3)))
    for previous, estimate in zip(estimates, estimates[1:]):
        step = se2.relative(previous.pose, estimate.pose)
        expected = expected.propagate(previous.pose, step, estimate.step_covariance, model)
    pipeline.config.acceptance.max_correction_linear = 1e-9
    rejected = pipeline.process(office_run.scans[3])
    assert rejected.status == 'rejected'
    # Ignorance: the motion is anywhere in the (default) window, 1.5 m and 90 deg.
    np.testing.assert_allclose(rejected.step_covariance,
                               np.diag([2.25, 2.25, (np.pi / 2) ** 2]), rtol=1e-12)
    step = se2.relative(estimates[-1].pose, rejected.pose)
    white = expected.propagate(estimates[-1].pose, step, rejected.step_covariance,
                               StepErrorModel())
    shared = expected.propagate(estimates[-1].pose, step, rejected.step_covariance, model)
    np.testing.assert_allclose(rejected.pose_covariance, white.pose_covariance, rtol=1e-9)
    assert not np.allclose(white.pose_covariance, shared.pose_covariance, rtol=1e-3)


@pytest.fixture(scope='module')
def turning_run():
    """Three seconds of driving at 0.3 m/s and turning at 0.8 rad/s (no sweep timing)."""
    from laser_odom.core.simulation.motions import ConstantTwist
    return simulate('office', 3.0, motion=ConstantTwist(0.3, 0.8, (1.0, 0.5, 0.0)), seed=1)


@pytest.mark.parametrize('distance, angle', [(0.25, 0.0), (0.0, 0.2), (0.25, 100.0)])
def test_keyframe_is_replaced_once_the_robot_moved_or_turned_far_enough(
        turning_run, distance, angle):
    """The reference is kept until the distance or the angle from it reaches its setting.

    A setting of 0 is off (both 0: scan to scan).
    """
    config = PipelineConfig(matcher='icp')
    config.keyframes.keyframe_distance = distance
    config.keyframes.keyframe_angle = angle
    pipeline = OdometryPipeline(config)
    pipeline.process(turning_run.scans[0])
    replaced = 0
    for scan in turning_run.scans[1:]:
        keyframe, keyframe_pose = pipeline.keyframe, pipeline.keyframe_pose.copy()
        estimate = pipeline.process(scan)
        assert estimate.status == 'matched'
        offset = se2.relative(keyframe_pose, estimate.pose)
        far = ((distance > 0.0 and np.hypot(offset[0], offset[1]) >= distance)
               or (angle > 0.0 and abs(offset[2]) >= angle))
        assert (pipeline.keyframe is not keyframe) == far, (distance, angle, offset)
        replaced += far
    assert 3 <= replaced <= 15
    scan_to_scan = OdometryPipeline(PipelineConfig(matcher='icp'))
    for scan in turning_run.scans[:4]:
        scan_to_scan.process(scan)
        assert scan_to_scan.keyframe.stamp_ns == scan.stamp_ns


def test_configure_keeps_or_replaces_the_matcher_and_the_reference(office_run):
    """A new matcher or matcher setting replaces the matcher; a new mounting the reference.

    Same settings: the same matcher and reference. A new mounting drops the reference
    and integration restarts from the current pose.
    """
    import copy
    pipeline = OdometryPipeline(PipelineConfig(matcher='icp'))
    for scan in office_run.scans[:5]:
        pipeline.process(scan)
    matcher, keyframe, pose = pipeline.matcher, pipeline.keyframe, pipeline.pose.copy()
    pipeline.configure(copy.deepcopy(pipeline.config))
    assert pipeline.matcher is matcher and pipeline.keyframe is keyframe
    config = copy.deepcopy(pipeline.config)
    config.matcher_config.max_iterations += 7
    pipeline.configure(config)
    assert pipeline.matcher is not matcher and pipeline.matcher.name == 'icp'
    assert pipeline.matcher.config.max_iterations == matcher.config.max_iterations + 7
    assert pipeline.keyframe is keyframe
    config = copy.deepcopy(pipeline.config)
    config.matcher, config.matcher_config = 'plicp', None
    pipeline.configure(config)
    assert pipeline.matcher.name == 'plicp' and pipeline.keyframe is keyframe
    assert pipeline.process(office_run.scans[5]).status == 'matched'
    config = copy.deepcopy(pipeline.config)
    config.mounting.laser_x = 0.1
    moved = pipeline.pose.copy()
    assert np.hypot(*(moved - pose)[:2]) > 0.01
    pipeline.configure(config)
    assert pipeline.keyframe is None
    estimate = pipeline.process(office_run.scans[6])
    assert estimate.status == 'initialized'
    np.testing.assert_array_equal(estimate.pose, moved)


def test_keyframe_expires_at_exactly_its_distance_or_angle():
    """The distance and angle settings are reached inclusively; 0 switches one off."""
    config = PipelineConfig(matcher='icp')
    pipeline = OdometryPipeline(config)
    expired = pipeline._keyframe_expired
    assert expired(se2.pose()) and expired(se2.pose(0.001, 0.0, 0.0))  # both 0: always
    config.keyframes.keyframe_distance, config.keyframes.keyframe_angle = 0.5, 0.0
    assert expired(se2.pose(0.3, -0.4, 0.0)) and not expired(se2.pose(0.3, 0.399, 3.0))
    config.keyframes.keyframe_distance, config.keyframes.keyframe_angle = 0.0, 0.25
    assert expired(se2.pose(0.0, 0.0, -0.25)) and not expired(se2.pose(9.0, 9.0, 0.249))
    config.keyframes.keyframe_distance = 0.5
    assert expired(se2.pose(0.5, 0.0, 0.0)) and expired(se2.pose(0.0, 0.0, 0.25))
    assert not expired(se2.pose(0.49, 0.0, 0.24))


def test_a_skipped_scan_is_said_with_its_stamp_and_reason(office_run):
    """A scan rejected by validation is counted under its reason and said with its stamp."""
    from laser_odom.core.events import EventLog
    said = []
    pipeline = OdometryPipeline(PipelineConfig(matcher='icp'), events=EventLog(said.append))
    scan = office_run.scans[7]
    empty = LaserScan(scan.stamp_ns, scan.angle_min, scan.angle_max, scan.angle_increment,
                      scan.range_min, scan.range_max, np.zeros(0))
    assert pipeline.process(empty) is None
    assert pipeline.counters['empty_scan'] == 1 and pipeline.counters['processed'] == 0
    assert said == [f'scan at t={scan.stamp_ns * 1e-9:.3f} skipped: scan has no ranges']


def test_a_stamp_equal_to_the_last_is_a_duplicate_even_as_another_int_object(office_run):
    """Stamps from a driver are new int objects each time: equal is what counts."""
    pipeline = OdometryPipeline(PipelineConfig(matcher='icp'))
    for scan in office_run.scans[:3]:
        pipeline.process(scan)
    again = replace_stamp(office_run.scans[2], int(str(office_run.scans[2].stamp_ns)))
    assert again.stamp_ns is not office_run.scans[2].stamp_ns
    assert pipeline.process(again) is None
    assert pipeline.counters['duplicate_stamp'] == 1 and pipeline.counters['processed'] == 3


def test_switching_the_matcher_type_forgets_how_matches_usually_fit(office_run):
    """The usual residual and inlier ratio belong to one matcher's metric."""
    from laser_odom.core.matchers import matcher_class
    pipeline = OdometryPipeline(PipelineConfig(matcher='icp'))
    for scan in office_run.scans[:12]:
        pipeline.process(scan)
    usual = pipeline.registrar.usual
    residual = usual.residual()
    assert residual is not None and usual.inlier_ratio() is not None
    pipeline.set_matcher(matcher_class('icp')(pipeline.matcher.config))
    assert usual.residual() == residual  # another icp: the same metric
    pipeline.set_matcher(matcher_class('plicp')(PipelineConfig(
        matcher='plicp').resolved_matcher_config()))
    assert usual.residual() is None and usual.inlier_ratio() is None
    assert pipeline.config.matcher == 'plicp'


def test_a_degenerate_step_compounds_white_whatever_the_matchers_shares(office_run):
    """A degenerate match's covariance is ignorance: propagated with the white model."""
    from laser_odom.core.uncertainty.pose_uncertainty import PoseUncertainty, StepErrorModel
    config = PipelineConfig(matcher='plicp')
    config.acceptance.degeneracy_min_information = 1e12  # every direction weak
    pipeline = OdometryPipeline(config)
    assert StepErrorModel.of(pipeline.matcher.config).shared_scan > 0.0
    estimates = [pipeline.process(scan) for scan in office_run.scans[:5]]
    white = PoseUncertainty.at(np.zeros((3, 3)))
    for previous, estimate in zip(estimates, estimates[1:]):
        assert estimate.status == 'degenerate'
        step = se2.relative(previous.pose, estimate.pose)
        white = white.propagate(previous.pose, step, estimate.step_covariance,
                                StepErrorModel())
        np.testing.assert_allclose(estimate.pose_covariance, white.pose_covariance,
                                   rtol=1e-9)


def test_a_rejected_scan_becomes_the_reference_even_between_keyframes(office_run):
    """After a rejection the current scan is the reference, whatever the keyframe rules."""
    config = PipelineConfig(matcher='icp')
    config.search.global_search = 'off'
    config.keyframes.keyframe_distance = 5.0
    pipeline = OdometryPipeline(config)
    for scan in office_run.scans[:4]:
        pipeline.process(scan)
    assert pipeline.keyframe.stamp_ns == office_run.scans[0].stamp_ns
    pipeline.config.acceptance.max_correction_linear = 1e-9
    assert pipeline.process(office_run.scans[4]).status == 'rejected'
    assert pipeline.keyframe.stamp_ns == office_run.scans[4].stamp_ns
    np.testing.assert_array_equal(pipeline.keyframe_pose, pipeline.pose)


def test_processing_time_statistics_cover_the_last_thousand_scans():
    """The node's timing diagnostics read the last TIMING_WINDOW = 1000 processing times."""
    pipeline = OdometryPipeline(PipelineConfig(matcher='icp'))
    pipeline.processing_times.extend(float(k) for k in range(1200))
    assert len(pipeline.processing_times) == 1000
    assert pipeline.processing_times[0] == 200.0 and pipeline.processing_times[-1] == 1199.0


def test_an_odometry_prior_is_trusted_and_a_rejection_advances_by_it(office_run):
    """With prior odom the matches start from the wheel odometry: no search after the first.

    A rejection then advances by that prediction, and says so.
    """
    from laser_odom.core.events import EventLog
    said = []
    config = PipelineConfig(matcher='icp')
    config.motion.prior = 'odom'
    pipeline = OdometryPipeline(config, events=EventLog(said.append))
    truth = office_run.reference.poses
    for k, scan in enumerate(office_run.scans[:6]):
        prior = se2.relative(truth[k - 1], truth[k]) if k else None
        estimate = pipeline.process(scan, prior_step=prior)
        assert estimate.status in ('initialized', 'matched')
    assert pipeline.counters['search_reset'] == 1
    assert pipeline.counters['search_no_prior'] == 0
    pipeline.config.acceptance.max_correction_linear = 1e-9
    pipeline.config.search.global_search = 'off'
    prior = se2.relative(truth[5], truth[6])
    before = pipeline.pose.copy()
    assert pipeline.process(office_run.scans[6], prior_step=prior).status == 'rejected'
    np.testing.assert_allclose(pipeline.pose, se2.compose(before, prior), atol=1e-12)
    assert said[-1].endswith('; advancing by the prediction')


def test_settings_named_as_a_parameter_file_gives_them_act_like_the_literals(office_run):
    """Equal strings that are not the same object: prior none, predict, the matcher name."""
    from laser_odom.core.events import EventLog
    said = []
    config = PipelineConfig(matcher='icp')
    config.motion.prior = ''.join(list('none'))
    config.acceptance.rejected_motion = ''.join(list('predict'))
    pipeline = OdometryPipeline(config, events=EventLog(said.append))
    for scan in office_run.scans[:4]:
        pipeline.process(scan)
    assert pipeline.counters['search_no_prior'] == 3  # every match searched
    pipeline.config.acceptance.max_correction_linear = 1e-9
    pipeline.config.search.global_search = 'off'
    assert pipeline.process(office_run.scans[4]).status == 'rejected'
    assert said[-1].endswith('; holding the pose (prior none: no prediction to advance by)')
    matcher = pipeline.matcher
    import copy
    same = copy.deepcopy(pipeline.config)
    same.matcher = ''.join(list('icp'))
    pipeline.configure(same)
    assert pipeline.matcher is matcher
    predict = OdometryPipeline(PipelineConfig(matcher='icp'), events=EventLog(said.append))
    predict.config.acceptance.rejected_motion = ''.join(list('predict'))
    predict.config.acceptance.max_correction_linear = 1e-9
    predict.config.search.global_search = 'off'
    predict.process(office_run.scans[0])
    assert predict.process(office_run.scans[1]).status == 'rejected'
    assert said[-1].endswith('; advancing by the prediction')


def test_switching_to_any_other_matcher_type_forgets_the_usual_fit(office_run):
    """From plicp to icp as from icp to plicp: the usual fit is forgotten."""
    from laser_odom.core.matchers import matcher_class
    pipeline = OdometryPipeline(PipelineConfig(matcher='plicp'))
    for scan in office_run.scans[:12]:
        pipeline.process(scan)
    assert pipeline.registrar.usual.residual() is not None
    pipeline.set_matcher(matcher_class('icp')(PipelineConfig(
        matcher='icp').resolved_matcher_config()))
    assert pipeline.registrar.usual.residual() is None


def test_the_global_search_is_said_with_its_trigger_and_the_local_failure(office_run):
    """A search after a gap says the trigger; after a failed local match also the failure."""
    from laser_odom.core.events import EventLog
    said = []
    pipeline = OdometryPipeline(PipelineConfig(matcher='icp'), events=EventLog(said.append))
    scans = office_run.scans
    for scan in scans[:3]:
        pipeline.process(scan)
    late = replace_stamp(scans[3], scans[2].stamp_ns + 1_500_000_000)
    pipeline.process(late)
    at = f't={late.stamp_ns * 1e-9:.3f}'
    assert said[-1].startswith(f'global search at {at}: the motion prior was dropped after a '
                               'gap between scans; best of ')
    pipeline.config.acceptance.max_correction_linear = 1e-9  # the local match fails
    shifted = replace_stamp(scans[4], late.stamp_ns + 100_000_000)
    pipeline.process(shifted)
    at = f't={shifted.stamp_ns * 1e-9:.3f}'
    searches = [line for line in said if line.startswith(f'global search at {at}')]
    assert len(searches) == 1
    assert searches[0].startswith(f'global search at {at}: the match from the prediction '
                                  'failed (')


def test_a_logger_stamping_late_then_early_publishes_the_robots_twist(office_run):
    """fr079's stamps: every scan a period apart, a fifth stamped 0.55 then 1.45 periods.

    The twist is the step over the scan period (the mean interval), not over the stamps'
    interval: over 0.55 of a period it would be 1.8 times the robot's.
    """
    intervals = [0.1, 0.1, 0.1, 0.055, 0.145]
    stamps = np.cumsum([0.0] + [intervals[k % 5] for k in range(len(office_run.scans) - 1)])
    pipeline = OdometryPipeline(PipelineConfig(matcher='plicp'))
    truth = office_run.reference.poses
    checked = 0
    for k, scan in enumerate(office_run.scans):
        estimate = pipeline.process(replace_stamp(scan, int(round(stamps[k] * 1e9))))
        if k < 30:
            continue
        velocity = se2.relative(truth[k - 1], truth[k])[0] / 0.1
        if velocity > 0.1:
            assert abs(estimate.twist[0] - velocity) < 0.1 * velocity, (k, estimate.twist)
            checked += 1
    assert checked > 50
