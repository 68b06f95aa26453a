"""De-skewing in the pipeline: matching again with the measured twist; keyframe preparation."""

import numpy as np
import pytest

from laser_odom.core import se2
from laser_odom.core.configuration.pipeline import PipelineConfig
from laser_odom.core.pipeline.odometry import OdometryPipeline
from laser_odom.core.simulation import simulate


def swept_run(stamp_at: str):
    """Three seconds of a 5 Hz LDS-01 turning at 1.5 rad/s: each sweep is bent by 0.3 rad."""
    from laser_odom.core.simulation.motions import ConstantTwist
    from laser_odom.core.simulation.sensors import sensor_model
    return simulate('office', 3.0, sensor_model('lds01', stamp_at=stamp_at),
                    motion=ConstantTwist(0.3, 1.5, (1.0, 0.5, 0.0)), seed=1)


def swept_pipeline(deskew='auto', prior='constant_velocity', stamp='first_beam',
                   global_search='recover'):
    """Return an icp pipeline and the number of matcher calls it made for each scan."""
    config = PipelineConfig(matcher='icp')
    config.scan.deskew, config.scan.scan_stamp = deskew, stamp
    config.motion.prior, config.search.global_search = prior, global_search
    pipeline = OdometryPipeline(config)
    calls = []
    match = pipeline.matcher.match

    def counted(*args, **kwargs):
        calls.append(1)
        return match(*args, **kwargs)
    pipeline.matcher.match = counted
    return pipeline, calls


def step_rotation_errors(estimates, truth) -> np.ndarray:
    poses = np.array([estimate.pose for estimate in estimates])
    return np.array([abs(se2.wrap_angle(se2.relative(poses[k - 1], poses[k])[2]
                                        - se2.relative(truth[k - 1], truth[k])[2]))
                     for k in range(1, len(poses))])


def test_without_a_prediction_the_measured_twist_deskews_the_scans_and_matches_again():
    """Prior none: the scans are de-skewed with the twist the first match measures.

    Matched again, the step rotation errors fall from 14 mrad (the sweep's bend) to 2.
    """
    data = swept_run('first')
    errors = {}
    for deskew in ('off', 'auto'):
        pipeline, _ = swept_pipeline(deskew, prior='none')
        estimates = [pipeline.process(scan) for scan in data.scans]
        assert [e.status for e in estimates[1:]] == ['matched'] * (len(data.scans) - 1)
        errors[deskew] = step_rotation_errors(estimates, data.reference.poses).mean()
    assert errors['off'] > 0.01
    assert errors['auto'] < 0.004 and errors['auto'] < 0.3 * errors['off']


@pytest.mark.parametrize('stamp_at', ['first', 'last'])
def test_a_good_prediction_is_not_matched_again(stamp_at):
    """With a constant-velocity prediction most scans need one match (the twist agrees).

    Stamped at the first beam the keyframe is de-skewed with the prediction before the
    match; stamped at the last its sweep is already known.
    """
    data = swept_run(stamp_at)
    pipeline, calls = swept_pipeline(stamp=f'{stamp_at}_beam')
    counts = []
    for scan in data.scans:
        before = len(calls)
        assert pipeline.process(scan).status in ('initialized', 'matched')
        counts.append(len(calls) - before)
    assert counts[1] >= 2  # the first step: the reference's sweep is not known yet
    assert sum(count == 1 for count in counts[5:]) >= 5, str(counts)  # of 10


def test_the_first_match_is_kept_when_the_match_again_is_rejected():
    """A second match (after de-skewing with the measured twist) that fails is dropped.

    The second match is the one on the scan de-skewed again (another scan than the
    first match's; the first's other basins are looked for on the first's scan).
    """
    data = swept_run('first')
    pipeline, calls = swept_pipeline(global_search='off')
    pipeline.process(data.scans[0])
    real = pipeline.matcher.match
    results, again = [], []

    def second_fails(reference, current, guess):
        result = real(reference, current, guess)
        if results and current is not results[0][0]:
            result.converged = False
            again.append(result)
        results.append((current, result))
        return result
    pipeline.matcher.match = second_fails
    estimate = pipeline.process(data.scans[1])
    first = results[0][1]
    assert len(again) == 1 and estimate.status == 'matched'
    assert estimate.match is first
    np.testing.assert_allclose(estimate.pose, first.pose, atol=1e-12)  # from the origin
    assert not np.allclose(again[0].pose, first.pose, rtol=0.0, atol=1e-6)


@pytest.mark.parametrize('stamp_at', ['first', 'last'])
def test_a_keyframe_whose_sweep_follows_its_stamp_is_not_prepared(stamp_at):
    """Stamped at the first beam, a keyframe is de-skewed again: prepare_next skips it.

    Its sweep is measured by the next match, which de-skews it again. Stamped at the
    last beam it is prepared.
    """
    data = swept_run(stamp_at)
    pipeline, _ = swept_pipeline(stamp=f'{stamp_at}_beam')
    assert pipeline.process(data.scans[0]).status == 'initialized'
    assert pipeline.prepare_next() == 0.0  # its motion is not known yet
    for scan in data.scans[1:6]:
        assert pipeline.process(scan).status == 'matched'
        assert (pipeline.prepare_next() > 0.0) == (stamp_at == 'last')
        assert pipeline.keyframe_prepared == (stamp_at == 'last')


@pytest.mark.parametrize('rejected_motion', ['predict', 'hold'])
def test_a_rejected_match_is_not_deskewed_and_matched_again(rejected_motion):
    """A rejection stands: the pose it gives (prediction or hold) is not re-matched."""
    data = swept_run('first')
    pipeline, _ = swept_pipeline(global_search='off')
    pipeline.config.acceptance.rejected_motion = rejected_motion
    for scan in data.scans[:4]:
        pipeline.process(scan)
    real = pipeline.matcher.match
    results = []

    def first_fails(reference, current, guess):
        results.append(real(reference, current, guess))
        if len(results) == 1:
            results[-1].converged = False
        return results[-1]
    pipeline.matcher.match = first_fails
    assert pipeline.process(data.scans[4]).status == 'rejected'
    assert len(results) == 1


def test_a_keyframe_with_a_known_sweep_is_not_deskewed_again():
    """Stamped at the last beam, a held keyframe keeps its de-skewing when scans re-match."""
    data = swept_run('last')
    pipeline, calls = swept_pipeline(stamp='last_beam')
    pipeline.config.keyframes.keyframe_distance = 10.0
    pipeline.process(data.scans[0])
    pipeline.process(data.scans[1])  # the first match measures the reference's sweep
    keyframe = pipeline.keyframe
    counts = []
    for scan in data.scans[2:7]:
        before = len(calls)
        assert pipeline.process(scan).status == 'matched'
        counts.append(len(calls) - before)
        assert pipeline.keyframe is keyframe
    assert max(counts) >= 2  # some scans were de-skewed and matched again


def test_a_rejected_keyframe_is_not_prepared_its_sweep_is_unknown():
    """Stamped at the last beam, a scan that replaced a rejected match is de-skewed again."""
    data = swept_run('last')
    pipeline, _ = swept_pipeline(stamp='last_beam', global_search='off')
    for scan in data.scans[:3]:
        pipeline.process(scan)
    assert pipeline.prepare_next() > 0.0
    pipeline.config.acceptance.max_correction_linear = 1e-9
    assert pipeline.process(data.scans[3]).status == 'rejected'
    assert pipeline.keyframe.stamp_ns == data.scans[3].stamp_ns
    assert pipeline.prepare_next() == 0.0 and not pipeline.keyframe_prepared
