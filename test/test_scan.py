"""LaserScan -> points: angles, increments, range limits, invalid readings, mounting."""

import math

import numpy as np
import pytest

from laser_odom.core import se2
from laser_odom.core.scan.laser_scan import LaserMounting, LaserScan, scan_to_points


def make_scan(ranges, angle_min=-math.pi / 2, increment=math.pi / 2, range_min=0.1,
              range_max=10.0):
    ranges = np.asarray(ranges, dtype=float)
    return LaserScan(stamp_ns=5, angle_min=angle_min,
                     angle_max=angle_min + increment * (len(ranges) - 1),
                     angle_increment=increment, range_min=range_min, range_max=range_max,
                     ranges=ranges)


def test_angles_and_points():
    pts = scan_to_points(make_scan([1.0, 2.0, 3.0]))
    assert np.allclose(pts.points, [[0.0, -1.0], [2.0, 0.0], [0.0, 3.0]], atol=1e-12)
    assert list(pts.beam_index) == [0, 1, 2]
    assert pts.stamp_ns == 5


def test_negative_increment_sweeps_clockwise():
    pts = scan_to_points(make_scan([1.0, 2.0, 3.0], angle_min=math.pi / 2,
                                   increment=-math.pi / 2))
    assert np.allclose(pts.points, [[0.0, 1.0], [2.0, 0.0], [0.0, -3.0]], atol=1e-12)


def test_invalid_readings_are_dropped_and_indices_kept():
    ranges = [1.0, np.nan, np.inf, -np.inf, 0.05, 11.0, 2.0]
    pts = scan_to_points(make_scan(ranges, increment=0.1))
    assert list(pts.beam_index) == [0, 6]
    assert np.allclose(pts.ranges, [1.0, 2.0])
    assert np.all(np.isfinite(pts.points))


def test_range_limits_are_inclusive():
    pts = scan_to_points(make_scan([0.1, 10.0], increment=0.1))
    assert len(pts) == 2


def test_mounting_offset_and_yaw():
    mount = LaserMounting(x=0.2, y=-0.1, yaw=math.pi / 2)
    pts = scan_to_points(make_scan([1.0, 2.0, 3.0]), mount)
    raw = scan_to_points(make_scan([1.0, 2.0, 3.0]))
    assert np.allclose(pts.points, se2.transform_points(se2.pose(0.2, -0.1, math.pi / 2),
                                                        raw.points))


def test_upside_down_mirrors_the_scan():
    mount = LaserMounting(upside_down=True)
    pts = scan_to_points(make_scan([1.0, 2.0, 3.0]), mount)
    assert np.allclose(pts.points, [[0.0, 1.0], [2.0, 0.0], [0.0, -3.0]], atol=1e-12)


def test_tree_is_built_once():
    pts = scan_to_points(make_scan([1.0, 2.0, 3.0]))
    assert pts.bearing_index is pts.bearing_index


def validator(min_valid_points=3, deskew='auto', scan_stamp='first_beam', mounting=None,
              max_beams=2000):
    """Return a ScanValidator whose events are kept (said) in a list, on a frozen clock."""
    from laser_odom.core.configuration.pipeline import MountingConfig, ScanConfig
    from laser_odom.core.events import EventLog
    from laser_odom.core.preprocess.validation import ScanValidator
    said = []
    events = EventLog(said.append, clock=lambda: 0.0)
    config = ScanConfig(min_valid_points=min_valid_points, deskew=deskew,
                        scan_stamp=scan_stamp, max_beams=max_beams)
    return ScanValidator(config, mounting or MountingConfig(), events), said


def field_scan(n=8, **fields):
    """Return a scan of ``n`` beams of 2 m, 0.25 rad apart from -1 rad, with fields replaced."""
    values = {'stamp_ns': 5, 'angle_min': -1.0, 'angle_max': -1.0 + 0.25 * (n - 1),
              'angle_increment': 0.25, 'range_min': 0.1, 'range_max': 10.0,
              'ranges': np.full(n, 2.0)}
    values.update(fields)
    return LaserScan(**values)


def test_validator_rejects_each_malformed_field_with_its_reason():
    """Unreadable ranges, no ranges, non-finite or non-numeric angles, a zero increment."""
    check, _ = validator()
    assert check.check(field_scan())[1] == ''
    assert check.check(field_scan(n=4, angle_min=-1, angle_increment=1, angle_max=2))[1] == ''
    cases = [({'ranges': ['a', 'b', 'c']}, 'bad_ranges'),
             ({'ranges': {'a': 1.0}}, 'bad_ranges'),
             ({'ranges': np.zeros(0)}, 'empty_scan'),
             ({'angle_increment': 0.0}, 'zero_increment'),
             ({'angle_increment': 0}, 'zero_increment')]
    for name in ('angle_min', 'angle_max', 'angle_increment'):
        for value in (math.nan, math.inf, -math.inf, '0.25', None):
            cases.append(({name: value}, 'non_finite_angles'))
    for fields, reason in cases:
        points, said_reason = check.check(field_scan(**fields))
        assert points is None and said_reason == reason, (fields, said_reason)


def test_validator_rejects_a_span_over_two_pi_by_increment_or_by_angle_fields():
    """Either the beams' span or angle_max - angle_min over 2 pi + SPAN_TOLERANCE rejects."""
    from laser_odom.core.preprocess.validation import SPAN_TOLERANCE
    limit = 2.0 * math.pi + SPAN_TOLERANCE
    check, _ = validator(min_valid_points=2)
    # Two beams: the span is the increment itself, so the limit is met exactly.
    for increment in (limit, -limit):
        scan = field_scan(n=2, angle_min=0.0, angle_max=0.0, angle_increment=increment)
        assert check.check(scan)[1] == ''
    over = math.nextafter(limit, 10.0)
    for increment in (over, -over):
        scan = field_scan(n=2, angle_min=0.0, angle_max=0.0, angle_increment=increment)
        assert check.check(scan)[1] == 'span_over_2pi'
    # Increment small, angle fields too far apart (and vice versa).
    assert check.check(field_scan(angle_min=-3.2, angle_max=3.2))[1] == 'span_over_2pi'
    assert check.check(field_scan(angle_min=-1.0, angle_max=-1.0 + limit))[1] == ''
    assert check.check(field_scan(angle_min=0.5, angle_max=0.5 + limit - 1e-6))[1] == ''
    wide = field_scan(n=8, angle_min=0.0, angle_max=1.0, angle_increment=0.89)
    assert check.check(wide)[1] == ''
    wider = field_scan(n=8, angle_min=0.0, angle_max=1.0, angle_increment=0.9)
    assert check.check(wider)[1] == 'span_over_2pi'


def test_validator_warns_once_when_ranges_disagree_with_the_angle_fields_by_over_one():
    """Angle fields describing 8 +- 1 beams pass silently; 8 +- 2 warn once; ranges win."""
    for n, warned in ((8, 0), (7, 0), (9, 0), (6, 1), (10, 1)):
        check, said = validator()
        scan = field_scan(n=n, angle_max=-1.0 + 0.25 * 7)  # the fields say 8 beams
        points, reason = check.check(scan)
        assert reason == '' and len(points) == n
        assert check.events.counters['length_mismatch'] == warned, n
        check.check(scan)
        assert check.events.counters['length_mismatch'] == 2 * warned
        assert len(said) == warned
        if warned:
            assert f'scan has {n} ranges but its angle fields describe 8 beams' in said[0]
    # once: not said again even after the throttle period.
    clock = [0.0]
    check, said = validator()
    check.events.clock = lambda: clock[0]
    for _ in range(2):
        check.check(field_scan(n=6, angle_max=0.75))
        clock[0] += 100.0
    assert len(said) == 1


def test_validator_bad_range_limits_fall_back_to_every_finite_positive_reading():
    """NaN, negative, non-numeric or inverted limits: readings > 0 are kept, warned once."""
    ranges = np.array([0.0, 0.05, 0.5, 2.0, 12.0, 1e4, -1.0, math.nan])
    check, said = validator(min_valid_points=2)
    points, _ = check.check(field_scan(ranges=ranges))  # limits 0.1 .. 10
    np.testing.assert_array_equal(points.ranges, [0.5, 2.0])
    points, _ = check.check(field_scan(ranges=ranges, range_min=0.0, range_max=10.0))
    np.testing.assert_array_equal(points.ranges, [0.0, 0.05, 0.5, 2.0])
    points, _ = check.check(field_scan(ranges=ranges, range_min=0.05, range_max=12.0))
    np.testing.assert_array_equal(points.ranges, [0.05, 0.5, 2.0, 12.0])
    points, _ = check.check(field_scan(ranges=ranges, range_min=0.01, range_max=0.6))
    np.testing.assert_array_equal(points.ranges, [0.05, 0.5])  # a short-range sensor
    assert check.events.counters['bad_range_limits'] == 0 and not said
    bad = [(math.nan, 10.0), (0.1, math.nan), (-0.1, 10.0), (5.0, 5.0), (10.0, 0.1),
           (0.0, 0.0), (0.0, -1.0), ('0.1', 10.0), (0.1, None)]
    for low, high in bad:
        points, reason = check.check(field_scan(ranges=ranges, range_min=low,
                                                range_max=high))
        assert reason == ''
        np.testing.assert_array_equal(points.ranges, [0.05, 0.5, 2.0, 12.0, 1e4],
                                      err_msg=f'{low} {high}')
    assert check.events.counters['bad_range_limits'] == len(bad)
    assert len(said) == 1 and 'range_min' in said[0]
    check.events.clock = lambda: 1e6  # once: not said again after the throttle period
    check.check(field_scan(ranges=ranges, range_min=math.nan))
    assert len(said) == 1


def test_validator_warns_once_about_intensities_of_another_length():
    """No intensities, none or one per range are fine; any other count warns once."""
    check, said = validator()
    for intensities in (None, np.zeros(0), np.ones(8)):
        assert check.check(field_scan(intensities=intensities))[1] == ''
    assert check.events.counters['intensities_length'] == 0
    for count in (1, 7, 9, 16):
        assert check.check(field_scan(intensities=np.ones(count)))[1] == ''
    assert check.events.counters['intensities_length'] == 4
    assert said == ['scan has 1 intensities for 8 ranges; intensities are ignored']
    check.events.clock = lambda: 1e6  # once: not said again after the throttle period
    check.check(field_scan(intensities=np.ones(3)))
    assert len(said) == 1


def test_validator_needs_min_valid_points_readings():
    """Exactly min_valid_points valid readings pass; one fewer is too_few_points."""
    check, _ = validator(min_valid_points=5)
    ranges = np.array([2.0, math.nan, 2.0, 2.0, 50.0, 2.0, 2.0, math.inf])
    points, reason = check.check(field_scan(ranges=ranges))
    assert reason == '' and list(points.beam_index) == [0, 2, 3, 5, 6]
    ranges[6] = math.nan
    assert check.check(field_scan(ranges=ranges)) == (None, 'too_few_points')


def test_validator_gives_points_in_the_base_frame_of_the_mounting():
    """The validated points are the scan's, moved by the configured laser mounting."""
    from laser_odom.core.configuration.pipeline import MountingConfig
    mounting = MountingConfig(laser_x=0.3, laser_y=-0.1, laser_yaw=0.5)
    check, _ = validator(mounting=mounting)
    points, _ = check.check(field_scan())
    raw = scan_to_points(field_scan())
    np.testing.assert_allclose(points.points,
                               se2.transform_points(se2.pose(0.3, -0.1, 0.5), raw.points))


def test_validator_beam_times_fall_back_on_the_last_valid_increment_of_that_beam_count():
    """Kept beams get index * time_increment; a NaN increment takes the last valid one."""
    check, _ = validator()
    ranges = np.array([2.0, math.nan, 2.0, 2.0, 2.0, 2.0, 2.0, 2.0])
    points, _ = check.check(field_scan(ranges=ranges, time_increment=1e-3, scan_time=0.1))
    np.testing.assert_allclose(points.times, [0.0, 2e-3, 3e-3, 4e-3, 5e-3, 6e-3, 7e-3])
    assert check.check(field_scan(time_increment=0.0))[0].times is None  # auto: not de-skewed
    for bad in (math.nan, 1.0):  # NaN, or a sweep of 7 s in a scan of 0.1 s
        points, _ = check.check(field_scan(time_increment=bad, scan_time=0.1))
        np.testing.assert_allclose(points.times, np.arange(8) * 1e-3)
    assert check.events.counters['time_increment_invalid'] == 2
    # Another beam count has no valid increment yet: not de-skewed.
    assert check.check(field_scan(n=9, time_increment=math.nan))[0].times is None
    # An invalid increment is not remembered as valid.
    assert check.check(field_scan(n=9, time_increment=1.0, scan_time=0.1))[0].times is None
    # The name as a parameter file gives it: equal to the literal, not the same object.
    last, _ = validator(scan_stamp=''.join(list('last_beam')))
    points, _ = last.check(field_scan(time_increment=1e-3))
    np.testing.assert_allclose(points.times, (np.arange(8) - 7) * 1e-3)
    off, _ = validator(deskew='off')
    assert off.check(field_scan(time_increment=1e-3))[0].times is None


@pytest.mark.parametrize('scan_stamp, time_increment, kept', [
    ('first_beam', 1e-4, 0), ('last_beam', 1e-4, 9), ('first_beam', -1e-4, 9),
    ('last_beam', -1e-4, 0)])
def test_a_scan_over_max_beams_is_matched_on_every_kth_beam_keeping_the_stamped_one(
        scan_stamp, time_increment, kept):
    """10 beams, max_beams 4: one beam in 3; the beam the stamp belongs to is kept."""
    check, said = validator(scan_stamp=scan_stamp, max_beams=4)
    ranges = 2.0 + 0.1 * np.arange(10)
    scan = field_scan(n=10, ranges=ranges, time_increment=time_increment, scan_time=0.1,
                      intensities=np.arange(10.0))
    full, _ = validator(scan_stamp=scan_stamp, max_beams=0)[0].check(scan)
    thinned = check.thin(scan)
    points, reason = check.check(thinned)
    beams = np.arange(kept % 3, 10, 3)
    assert reason == '' and len(points) == len(beams)
    np.testing.assert_allclose(points.points, full.points[beams], atol=1e-12)
    np.testing.assert_allclose(points.times, full.times[beams], atol=1e-15)
    np.testing.assert_allclose(thinned.intensities, np.arange(10.0)[beams])
    assert check.events.counters['length_mismatch'] == 0
    check.thin(scan)
    assert check.events.counters['scan_thinned'] == 2
    assert sum('more than max_beams (4): one beam in 3 is matched' in s for s in said) == 1


def test_max_beams_zero_or_above_the_count_keeps_the_scan():
    scan = field_scan(n=10)
    assert validator(max_beams=0)[0].thin(scan) is scan
    assert validator(max_beams=10)[0].thin(scan) is scan
