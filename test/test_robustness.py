"""Hard to break: malformed scans never crash the pipeline or corrupt the pose."""

import math

import numpy as np
import pytest

from laser_odom.core import se2
from laser_odom.core.configuration.pipeline import PipelineConfig
from laser_odom.core.events import EventLog
from laser_odom.core.matchers import matcher_names
from laser_odom.core.pipeline.odometry import OdometryPipeline
from laser_odom.core.preprocess.deskew import DESKEW_EVENTS
from laser_odom.core.preprocess.validation import REJECTIONS
from laser_odom.core.scan.laser_scan import LaserScan
from laser_odom.core.simulation import get_world, LaserModel, render_scan

MALFORMATIONS = (
    'empty', 'nan_angle', 'inf_angle', 'zero_increment', 'span_over_2pi',
    'length_mismatch', 'bad_range_limits', 'intensities_length', 'garbage_ranges',
    'all_invalid', 'negative_increment', 'huge_values', 'tiny_scan', 'nan_time_increment',
    'negative_time_increment', 'sweep_longer_than_scan', 'no_time_increment', 'no_timing')


def malformed_scan(rng: np.random.Generator, stamp_ns: int) -> LaserScan:
    """Return a scan with one or more random defects and a random length (0..20000)."""
    n = int(rng.choice([0, 1, 2, 5, 50, 360, 1081, 5000, 20000, rng.integers(0, 20001)]))
    increment = 2 * math.pi / max(n, 1) * rng.uniform(0.1, 1.0)
    angle_min = rng.uniform(-math.pi, 0.0)
    ranges = rng.uniform(0.1, 15.0, n)
    fields = {'stamp_ns': stamp_ns, 'angle_min': angle_min,
              'angle_max': angle_min + increment * max(n - 1, 0),
              'angle_increment': increment, 'range_min': 0.05, 'range_max': 20.0,
              'ranges': ranges, 'intensities': None, 'frame_id': 'laser',
              'scan_time': 0.1, 'time_increment': 0.1 * increment / (2 * math.pi)}
    for defect in rng.choice(MALFORMATIONS, size=rng.integers(1, 4), replace=False):
        if defect == 'empty':
            fields['ranges'] = np.zeros(0)
        elif defect == 'nan_angle':
            fields[rng.choice(['angle_min', 'angle_max', 'angle_increment'])] = math.nan
        elif defect == 'inf_angle':
            fields[rng.choice(['angle_min', 'angle_max', 'angle_increment'])] = -math.inf
        elif defect == 'zero_increment':
            fields['angle_increment'] = 0.0
        elif defect == 'span_over_2pi':
            fields['angle_increment'] = 7.0 / max(n - 1, 1)
            fields['angle_max'] = fields['angle_min'] + 7.0
        elif defect == 'length_mismatch':
            fields['angle_max'] = fields['angle_min'] + increment * rng.integers(0, 3 * n + 2)
        elif defect == 'bad_range_limits':
            fields['range_min'], fields['range_max'] = rng.choice(
                [(math.nan, 20.0), (-1.0, 20.0), (30.0, 1.0), (0.1, math.nan), (0.0, -5.0)])
        elif defect == 'intensities_length':
            fields['intensities'] = np.ones(int(rng.integers(0, 2 * n + 2)))
        elif defect == 'garbage_ranges':
            bad = rng.random(n) < rng.random()
            fields['ranges'] = np.where(bad, rng.choice([np.nan, np.inf, -np.inf, -1.0, 0.0],
                                                        n), ranges)
        elif defect == 'all_invalid':
            fields['ranges'] = np.full(n, np.nan)
        elif defect == 'negative_increment':
            fields['angle_increment'] = -abs(fields['angle_increment'])
        elif defect == 'huge_values':
            fields['ranges'] = ranges * 1e30
            fields['range_max'] = math.inf
        elif defect == 'tiny_scan':
            fields['ranges'] = ranges[:3]
        elif defect == 'nan_time_increment':
            fields['time_increment'] = rng.choice([math.nan, math.inf, -math.inf])
        elif defect == 'negative_time_increment':
            fields['time_increment'] = -fields['time_increment']
        elif defect == 'sweep_longer_than_scan':
            fields['time_increment'] = rng.uniform(0.2, 10.0) / max(n - 1, 1)
        elif defect == 'no_time_increment':
            fields['time_increment'] = 0.0
        elif defect == 'no_timing':
            fields['time_increment'], fields['scan_time'] = 0.0, rng.choice([0.0, math.nan])
    return LaserScan(**fields)


def good_scans(start_ns: int):
    """Two good office scans 0.1 s apart, and the true motion between them."""
    path = get_world('office').path
    poses = path.poses_at(np.array([5.0, 5.1]))
    rng = np.random.default_rng(9)
    scans = [render_scan('office', poses[k], LaserModel(), rng, start_ns + k * 100_000_000)
             for k in range(2)]
    return scans, se2.relative(poses[0], poses[1])


def assert_finite(estimate) -> None:
    for value in (estimate.pose, estimate.pose_covariance, estimate.twist,
                  estimate.twist_covariance):
        assert np.all(np.isfinite(value))


# Each malformed scan that passes validation is matched (and de-skewed, and matched again),
# and a failed match runs the global search and refines its best poses: a few seconds
# for a random scan of 20,000 beams thinned to max_beams (half a minute before it was).
# 200 scans produce each of the 18 defects about 20 times per matcher, and every
# rejection and warning below.
@pytest.mark.parametrize('matcher, count', [(name, 200) for name in matcher_names()])
def test_fuzzed_scans_never_escape_or_corrupt(matcher, count):
    rng = np.random.default_rng(sum(map(ord, matcher)))
    said = []
    config = PipelineConfig(matcher=matcher)
    config.scan.deskew = 'on'  # also repairs a zero time_increment from scan_time
    # A frozen clock: within one throttle period each reason may be said only once.
    pipeline = OdometryPipeline(config, events=EventLog(said.append, clock=lambda: 0.0))
    stamp = 1_000_000_000
    for _ in range(count):
        stamp += int(rng.integers(1, 200_000_000))
        estimate = pipeline.process(malformed_scan(rng, stamp))
        if estimate is not None:
            assert_finite(estimate)
    counters = pipeline.counters
    assert counters['scans_in'] == count
    assert counters['matcher_error'] == 0, said
    for reason in REJECTIONS:
        if reason != 'bad_ranges':
            assert counters[reason] > 0, reason
    for warning in ('length_mismatch', 'bad_range_limits', 'intensities_length', 'scan_thinned',
                    *DESKEW_EVENTS):
        assert counters[warning] > 0, warning
    reasons = [reason for reason, count in counters.items() if count]
    assert len(said) <= len(reasons)  # throttled: one line per reason, not one per scan
    # A good scan pair afterwards is matched correctly.
    pipeline.reset()
    scans, truth = good_scans(stamp + 1_000_000_000)
    pipeline.process(scans[0])
    estimate = pipeline.process(scans[1])
    assert estimate.status == 'matched'
    assert np.hypot(*(estimate.pose[:2] - truth[:2])) < 0.01
    assert abs(se2.wrap_angle(estimate.pose[2] - truth[2])) < math.radians(0.3)


def test_each_rejection_has_its_reason():
    pipeline = OdometryPipeline(PipelineConfig(), events=EventLog(lambda _: None))
    base = good_scans(10)[0][0]
    cases = {
        'empty_scan': {'ranges': np.zeros(0)},
        'non_finite_angles': {'angle_increment': math.nan},
        'zero_increment': {'angle_increment': 0.0},
        'span_over_2pi': {'angle_max': base.angle_min + 7.0, 'angle_increment': 0.1},
        'too_few_points': {'ranges': np.full(len(base.ranges), np.inf)},
        'bad_ranges': {'ranges': ['a', 'b']},
    }
    for reason, change in cases.items():
        fields = dict(vars(base))
        fields.update(change)
        assert pipeline.process(LaserScan(**fields)) is None
        assert pipeline.counters[reason] == 1, reason


def test_repairable_fields_are_used_and_said_once():
    said = []
    pipeline = OdometryPipeline(PipelineConfig(), events=EventLog(said.append))
    base = good_scans(10)[0][0]
    for k in range(20):
        fields = dict(vars(base))
        fields.update(stamp_ns=base.stamp_ns + k * 100_000_000, range_min=math.nan,
                      angle_max=base.angle_max - 1.0, intensities=np.ones(3))
        assert pipeline.process(LaserScan(**fields)) is not None
    assert pipeline.counters['bad_range_limits'] == 20
    assert pipeline.counters['length_mismatch'] == 20
    assert pipeline.counters['intensities_length'] == 20
    assert len(said) == 3


def test_warnings_are_throttled_per_reason():
    now = [0.0]
    said = []
    events = EventLog(said.append, period=10.0, clock=lambda: now[0])
    for second in range(40):
        now[0] = float(second)
        for _ in range(40):  # a 40 Hz sensor sending only bad scans
            events.warn('empty_scan', 'scan skipped')
    assert events.counters['empty_scan'] == 1600
    assert len(said) == 4
    assert '(400 times' in said[1]
