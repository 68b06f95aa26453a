"""Tests of bag reading: ROS 1 and ROS 2 bags, sound, non-standard and cut off."""

from pathlib import Path
import shutil
import struct

import numpy as np
import pytest
from rosbags.rosbag1 import Writer as Writer1
from rosbags.typesys import get_typestore, Stores

from laser_odom.core import se2
from laser_odom.core.scan.laser_scan import LaserScan
from laser_odom.core.trajectory import Trajectory
from laser_odom.io.bag_reader import (
    BagFormatError, BagNotFoundError, BagReader, BagTruncatedError, TopicError)
from laser_odom.io.bag_sources import Ros1RecordSource, Ros2SalvageSource, RosbagsSource
from laser_odom.io.bag_writer import write_bag
from laser_odom.io.ros1_records import parse_header

N_SCANS = 40
NOETIC = get_typestore(Stores.ROS1_NOETIC)
T1 = NOETIC.types


def _scan(i: int) -> LaserScan:
    """Return scan ``i``: 180 beams whose ranges encode the index."""
    ranges = np.full(180, 1.0 + 0.01 * i)
    ranges[::7] = np.nan
    return LaserScan(stamp_ns=10**18 + i * 10**8, angle_min=-1.5, angle_max=1.5,
                     angle_increment=3.0 / 179, range_min=0.1, range_max=30.0, ranges=ranges,
                     frame_id='laser', scan_time=0.1)


def _odometry(n: int) -> Trajectory:
    """Return a curved wheel-odometry path with stamps between the scans."""
    i = np.arange(n)
    return Trajectory(10**18 + i * 5 * 10**7 + 1, np.column_stack(
        (0.05 * i, 0.01 * i ** 1.5, se2.wrap_angle(0.04 * i))))


def _write_ros1(path: Path, n: int = N_SCANS, compression=None, extra_scan_topic=False,
                imu=False) -> Path:
    """Write a ROS 1 bag with /scan and /odom (and optionally a 2nd scan topic, /imu)."""
    writer = Writer1(path)
    writer.chunk_threshold = 8000  # several chunks, so a cut leaves whole chunks behind
    if compression is not None:
        writer.set_compression(compression)
    header, time = T1['std_msgs/msg/Header'], T1['builtin_interfaces/msg/Time']
    with writer:
        scan_conn = writer.add_connection('/scan', 'sensor_msgs/msg/LaserScan',
                                          typestore=NOETIC)
        odom_conn = writer.add_connection('/odom', 'nav_msgs/msg/Odometry', typestore=NOETIC)
        other = (writer.add_connection('/scan2', 'sensor_msgs/msg/LaserScan', typestore=NOETIC)
                 if extra_scan_topic else None)
        imu_conn = (writer.add_connection('/imu', 'sensor_msgs/msg/Imu', typestore=NOETIC)
                    if imu else None)
        odom = _odometry(2 * n)
        for i in range(n):
            s = _scan(i)
            sec, nsec = divmod(s.stamp_ns, 10**9)
            msg = T1['sensor_msgs/msg/LaserScan'](
                header=header(seq=i, stamp=time(sec=sec, nanosec=nsec), frame_id='laser'),
                angle_min=s.angle_min, angle_max=s.angle_max, angle_increment=s.angle_increment,
                time_increment=0.0, scan_time=0.1, range_min=s.range_min,
                range_max=s.range_max, ranges=s.ranges.astype(np.float32),
                intensities=np.zeros(0, np.float32))
            raw = NOETIC.serialize_ros1(msg, 'sensor_msgs/msg/LaserScan')
            writer.write(scan_conn, s.stamp_ns, raw)
            if other is not None:
                writer.write(other, s.stamp_ns, raw)
            for k in (2 * i, 2 * i + 1):
                sec, nsec = divmod(int(odom.stamps_ns[k]), 10**9)
                qx, qy, qz, qw = se2.yaw_to_quaternion(odom.poses[k, 2])
                pose = T1['geometry_msgs/msg/Pose'](
                    position=T1['geometry_msgs/msg/Point'](
                        x=odom.poses[k, 0], y=odom.poses[k, 1], z=0.0),
                    orientation=T1['geometry_msgs/msg/Quaternion'](x=qx, y=qy, z=qz, w=qw))
                o = T1['nav_msgs/msg/Odometry'](
                    header=header(seq=k, stamp=time(sec=sec, nanosec=nsec), frame_id='odom'),
                    child_frame_id='base_link',
                    pose=T1['geometry_msgs/msg/PoseWithCovariance'](
                        pose=pose, covariance=np.zeros(36)),
                    twist=T1['geometry_msgs/msg/TwistWithCovariance'](
                        twist=T1['geometry_msgs/msg/Twist'](
                            linear=T1['geometry_msgs/msg/Vector3'](x=0.0, y=0.0, z=0.0),
                            angular=T1['geometry_msgs/msg/Vector3'](x=0.0, y=0.0, z=0.0)),
                        covariance=np.zeros(36)))
                writer.write(odom_conn, int(odom.stamps_ns[k]),
                             NOETIC.serialize_ros1(o, 'nav_msgs/msg/Odometry'))
            if imu_conn is not None:
                _write_imu(writer, imu_conn, i, s.stamp_ns)
    return path


def _write_imu(writer: Writer1, conn, i: int, stamp_ns: int) -> None:
    """Write one IMU sample: yaw 0.1 i with orientation on even i, rate 0.5 rad/s."""
    sec, nsec = divmod(stamp_ns, 10**9)
    qx, qy, qz, qw = se2.yaw_to_quaternion(0.1 * i)
    cov = np.zeros(9)
    if i % 2:
        cov[0] = -1.0
    msg = T1['sensor_msgs/msg/Imu'](
        header=T1['std_msgs/msg/Header'](seq=i, stamp=T1['builtin_interfaces/msg/Time'](
            sec=sec, nanosec=nsec), frame_id='imu'),
        orientation=T1['geometry_msgs/msg/Quaternion'](x=qx, y=qy, z=qz, w=qw),
        orientation_covariance=cov,
        angular_velocity=T1['geometry_msgs/msg/Vector3'](x=0.0, y=0.0, z=0.5),
        angular_velocity_covariance=np.zeros(9),
        linear_acceleration=T1['geometry_msgs/msg/Vector3'](x=0.0, y=0.0, z=9.8),
        linear_acceleration_covariance=np.zeros(9))
    writer.write(conn, stamp_ns, NOETIC.serialize_ros1(msg, 'sensor_msgs/msg/Imu'))


def _assert_scans_match(scans: list[LaserScan], count: int) -> None:
    """Check that ``scans`` are the first ``count`` written scans, intact."""
    assert len(scans) == count
    for i, scan in enumerate(scans):
        expected = _scan(i)
        assert scan.stamp_ns == expected.stamp_ns
        np.testing.assert_allclose(scan.ranges, expected.ranges, rtol=1e-6)
        assert scan.frame_id == 'laser' and scan.angle_min == pytest.approx(-1.5)


def _read_until_damage(bag: BagReader) -> tuple[list[LaserScan], BagTruncatedError | None]:
    """Return the scans read and the error that stopped reading, if any."""
    scans: list[LaserScan] = []
    try:
        for scan in bag.scans():
            scans.append(scan)
    except BagTruncatedError as err:
        return scans, err
    return scans, None


def test_sound_ros1_bag_reads_through_rosbags(tmp_path):
    path = _write_ros1(tmp_path / 'ok.bag')
    with BagReader(path) as bag:
        assert isinstance(bag._source, RosbagsSource)
        assert bag.topics == {'/scan': 'sensor_msgs/msg/LaserScan',
                              '/odom': 'nav_msgs/msg/Odometry'}
        scans, error = _read_until_damage(bag)
        odometry = bag.odometry('/odom')
    assert error is None
    _assert_scans_match(scans, N_SCANS)
    expected = _odometry(2 * N_SCANS)
    np.testing.assert_array_equal(odometry.stamps_ns, expected.stamps_ns)
    np.testing.assert_allclose(odometry.poses, expected.poses, atol=1e-9)


def _patch_index_lengths(path: Path) -> int:
    """Declare 20-byte entries in every index-data record (as the ccny demo bag does)."""
    data = bytearray(path.read_bytes())
    pos, patched = 13, 0
    while pos < len(data):
        (hlen,) = struct.unpack_from('<I', data, pos)
        header = parse_header(bytes(data[pos + 4:pos + 4 + hlen]))
        (dlen,) = struct.unpack_from('<I', data, pos + 4 + hlen)
        if header['op'][0] == 0x04:
            count = struct.unpack('<I', header['count'])[0]
            struct.pack_into('<I', data, pos + 4 + hlen, count * 20)
            patched += 1
        pos += 8 + hlen + dlen
    path.write_bytes(bytes(data))
    return patched


def test_nonstandard_index_is_read_record_by_record(tmp_path):
    path = _write_ros1(tmp_path / 'odd.bag')
    assert _patch_index_lengths(path) > 2
    with BagReader(path) as bag:
        assert isinstance(bag._source, Ros1RecordSource)
        assert bag.strict_error is not None
        scans, error = _read_until_damage(bag)
        assert len(bag.odometry('/odom')) == 2 * N_SCANS
    assert error is None
    _assert_scans_match(scans, N_SCANS)


@pytest.mark.parametrize('compression', [None, Writer1.CompressionFormat.BZ2,
                                         Writer1.CompressionFormat.LZ4])
def test_cut_ros1_bag_yields_intact_messages_then_error(tmp_path, compression):
    full = _write_ros1(tmp_path / 'full.bag', compression=compression)
    cut = tmp_path / 'cut.bag'
    data = full.read_bytes()
    cut.write_bytes(data[:int(len(data) * 0.6)])
    with BagReader(cut) as bag:
        assert isinstance(bag._source, Ros1RecordSource)
        scans, error = _read_until_damage(bag)
        odometry = bag.odometry('/odom', strict=False)
    assert error is not None and error.message_index == len(scans)
    assert 'reading stopped at message' in str(error) and '\n' not in str(error)
    assert 0 < len(scans) < N_SCANS
    _assert_scans_match(scans, len(scans))
    assert 0 < len(odometry) < 2 * N_SCANS


@pytest.mark.parametrize('storage,suffix', [('sqlite3', '.db3'), ('mcap', '.mcap')])
def test_cut_ros2_bag_yields_intact_messages_then_error(tmp_path, storage, suffix):
    scans = [_scan(i) for i in range(200)]
    write_bag(tmp_path / 'full', scans, odometry={'/odom': _odometry(50)}, storage=storage)
    with BagReader(tmp_path / 'full') as bag:
        assert isinstance(bag._source, RosbagsSource)
        _assert_scans_match(list(bag.scans()), 200)
    storage_file = next((tmp_path / 'full').glob('*' + suffix))
    with BagReader(storage_file) as bag:  # a single storage file is a bag too
        assert len(list(bag.scans())) == 200
    cut_dir = tmp_path / 'cut'
    shutil.copytree(tmp_path / 'full', cut_dir)
    cut_file = cut_dir / storage_file.name
    data = cut_file.read_bytes()
    cut_file.write_bytes(data[:len(data) // 2])
    for path in (cut_dir, cut_file):
        with BagReader(path) as bag:
            assert isinstance(bag._source, Ros2SalvageSource)
            read, error = _read_until_damage(bag)
        assert error is not None and error.message_index == len(read)
        assert 50 < len(read) < 200
        _assert_scans_match(read, len(read))


def test_imu_samples_with_and_without_orientation(tmp_path):
    path = _write_ros1(tmp_path / 'imu.bag', n=10, imu=True)
    with BagReader(path) as bag:
        imu = bag.imu(None)
    assert len(imu) == 10
    np.testing.assert_allclose(imu.yaw[0::2], 0.1 * np.arange(0, 10, 2), atol=1e-12)
    assert np.all(np.isnan(imu.yaw[1::2]))
    np.testing.assert_allclose(imu.yaw_rate, 0.5)


def test_topic_selection_errors(tmp_path):
    path = _write_ros1(tmp_path / 'two.bag', n=3, extra_scan_topic=True)
    with BagReader(path) as bag:
        with pytest.raises(TopicError, match='--scan-topic'):
            bag.select_topic('sensor_msgs/msg/LaserScan')
        assert bag.select_topic('sensor_msgs/msg/LaserScan', 'scan2') == '/scan2'
        with pytest.raises(TopicError, match='not sensor_msgs/msg/LaserScan'):
            bag.select_topic('sensor_msgs/msg/LaserScan', '/odom')
        with pytest.raises(TopicError, match='no topic /nope'):
            bag.select_topic('sensor_msgs/msg/LaserScan', '/nope')
    write_bag(tmp_path / 'noscan', odometry={'/odom': _odometry(5)})
    with BagReader(tmp_path / 'noscan') as bag:
        with pytest.raises(TopicError, match='no LaserScan topic'):
            list(bag.scans())


def test_a_wrong_topic_names_the_laser_scan_topics_there(tmp_path):
    """Issue 30.8: a mistyped --scan-topic is answered with the topics to choose from."""
    path = _write_ros1(tmp_path / 'two.bag', n=3, extra_scan_topic=True)
    with BagReader(path) as bag:
        with pytest.raises(TopicError) as missing:
            bag.select_topic('sensor_msgs/msg/LaserScan', '/front_scan')
        with pytest.raises(TopicError) as wrong_type:
            bag.select_topic('sensor_msgs/msg/LaserScan', '/odom')
        assert bag.message_count('/scan') == 3  # from the bag's index
    assert str(missing.value) == (f'{path}: no topic /front_scan in the bag; its LaserScan '
                                  'topics: /scan, /scan2')
    assert str(wrong_type.value).endswith('not sensor_msgs/msg/LaserScan; its LaserScan '
                                          'topics: /scan, /scan2')
    write_bag(tmp_path / 'noscan', odometry={'/odom': _odometry(5)})
    with BagReader(tmp_path / 'noscan') as bag:
        with pytest.raises(TopicError, match='no topic /scan in the bag; it has no LaserScan '
                           'topic$'):
            bag.select_topic('sensor_msgs/msg/LaserScan', 'scan')


def test_missing_and_foreign_paths(tmp_path):
    with pytest.raises(BagNotFoundError):
        BagReader(tmp_path / 'absent.bag')
    text = tmp_path / 'notes.bag'
    text.write_text('not a bag at all\n')
    with pytest.raises(BagFormatError):
        BagReader(text)
    with pytest.raises(BagFormatError):
        BagReader(tmp_path)  # a directory without storage files


def test_ccny_demo_bag_with_nonstandard_index(shared_data_dir):
    path = shared_data_dir / 'ccny-demo' / 'demo.bag'
    if not path.is_file():
        pytest.skip(f'{path} not available')
    with BagReader(path) as bag:
        assert bag.topics == {'/scan': 'sensor_msgs/msg/LaserScan'}
        scans, error = _read_until_damage(bag)
    assert error is None and len(scans) == 360
    stamps = np.array([s.stamp_ns for s in scans])
    assert np.all(np.diff(stamps) > 0)
    assert {len(s.ranges) for s in scans} == {681}
    assert scans[0].angle_min == pytest.approx(-2.086, abs=1e-3)
    valid = np.concatenate([s.ranges[np.isfinite(s.ranges)] for s in scans])
    assert 0.0 <= np.median(valid) <= 5.6
