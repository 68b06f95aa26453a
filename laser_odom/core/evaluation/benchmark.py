"""Score a matcher on a dataset: accuracy against the reference and time per scan.

The benchmark command, the real-data tests and the closing notes all use
:func:`benchmark_run`, so a figure in a note is the figure a test asserts.
"""

from __future__ import annotations

import dataclasses
from dataclasses import asdict, dataclass, fields
import math
from typing import Callable

import numpy as np

from laser_odom.core import se2
from laser_odom.core.configuration.node import PriorConfig
from laser_odom.core.configuration.pipeline import PipelineConfig, REFERENCES, ScanConfig
from laser_odom.core.evaluation.consistency import (
    Consistency, failed_steps, FailedSteps, NO_REFERENCE_NOISE, ReferenceNoise, run_consistency,
    WINDOWS)
from laser_odom.core.evaluation.metrics import evaluate, segment_drift
from laser_odom.core.events import EventLog
from laser_odom.core.matchers import default_config
from laser_odom.core.motion.priors import PriorFeed
from laser_odom.core.parameters import param_info
from laser_odom.core.pipeline.odometry import OdometryPipeline
from laser_odom.core.pipeline.runner import run_pipeline, RunResult
from laser_odom.core.simulation import ConstantTwist, LaserModel, sensor_model, simulate
from laser_odom.core.trajectory import Dataset, Trajectory
from laser_odom.core.uncertainty.pose_uncertainty import StepErrorModel

BENCH_PRIORS = {'none': 'none', 'constant_velocity': 'constant_velocity', 'odom': 'odom',
                'zero': 'none'}
"""Benchmark prior names -> the pipeline's ``prior`` parameter (``zero`` is the earlier
name of ``none``, still accepted)."""

DEFAULT_BENCH_PRIORS = ('none', 'constant_velocity', 'odom')
"""The priors a benchmark run scores unless told otherwise."""

WHEEL_ODOMETRY = 'wheel_odometry'
"""Pseudo-matcher name of the row that scores raw wheel odometry alone."""

NOT_APPLICABLE = '-'
"""The ``deskew`` of a row the setting does not apply to (the wheel odometry row)."""

DESKEW_MODES: tuple[str, ...] = tuple(param_info(ScanConfig, 'deskew').choices or ())
"""The pipeline's ``deskew`` values (``laser_odom_bench --deskew``)."""

REFERENCE_MODES: tuple[str, ...] = REFERENCES
"""The pipeline's ``reference`` values (``laser_odom_bench --reference-modes``)."""

WARMUP_SCANS = 10
"""Scans at the start of a run left out of the timing statistics (caches, imports)."""

REAL_REFERENCE_NOISE = ReferenceNoise.degrees(0.04, 1.0)
"""Noise of a real log's (SLAM-corrected) reference pose: 4 cm in x and y, 1 deg
(``../shared/data/README.md``: 3-5 cm, 1 deg); the NEES accounts for it
(:mod:`laser_odom.core.evaluation.consistency`). A simulated dataset's reference is the truth."""

NEES_FIELDS = {f'nees_{n}': n for n in WINDOWS}
"""The row fields of the windowed NEES: field -> window length [steps]."""


@dataclass(frozen=True)
class SimulatedSpec:
    """A simulated benchmark dataset: world, beams, field of view, duration, motion."""

    world: str
    beams: int
    fov_deg: float
    duration: float = 60.0
    seed: int = 1
    motion: str = 'gentle'
    drop: float = 0.0
    """Share of the scans dropped."""

    def generate(self, name: str) -> Dataset:
        """Simulate the dataset (deterministic for the spec)."""
        laser = LaserModel(beams=self.beams, fov=math.radians(self.fov_deg))
        dataset = simulate(self.world, duration=self.duration, laser=laser, seed=self.seed,
                           motion=self.motion, drop=self.drop)
        dataset.name = name
        return dataset


SIMULATED = {
    'sim-office-360': SimulatedSpec('office', 360, 360.0),
    'sim-corridor-360': SimulatedSpec('corridor', 360, 360.0),
    'sim-cluttered-360': SimulatedSpec('cluttered', 360, 360.0),
    'sim-office-1081': SimulatedSpec('office', 1081, 270.0),
    'sim-cluttered-1081': SimulatedSpec('cluttered', 1081, 270.0),
    'sim-gentle-drop20': SimulatedSpec('office', 360, 360.0, drop=0.2),
    'sim-spin-drop20': SimulatedSpec('office', 360, 360.0, motion='spin', drop=0.2),
    'sim-aggressive-drop20': SimulatedSpec('office', 360, 360.0, motion='aggressive',
                                           drop=0.2),
}
"""Simulated datasets of the benchmark: corridor-heavy and cluttered, 360 and 1081 beams;
and the office at 10 Hz with a fifth of the scans dropped, driven gently, spinning in
place (3 rad/s) and aggressively (1.5 m/s)."""


@dataclass(frozen=True)
class SensorSpec:
    """A simulated dataset of a sensor preset: world, motion, duration, seed."""

    sensor: str
    motion: str | ConstantTwist = 'gentle'
    duration: float = 60.0
    world: str = 'office'
    seed: int = 1
    rate: float | None = None
    """Scan rate [Hz] in place of the preset's (a lidar turned slower or faster)."""

    def generate(self, name: str) -> Dataset:
        """Simulate the dataset (deterministic for the spec)."""
        if self.rate is None:
            dataset = simulate(self.world, duration=self.duration, sensor=self.sensor,
                               seed=self.seed, motion=self.motion)
        else:
            dataset = simulate(self.world, duration=self.duration,
                               laser=sensor_model(self.sensor, rate=self.rate),
                               seed=self.seed, motion=self.motion)
        dataset.name = name
        return dataset


GRID_SENSORS = ('lds01', 'rplidar_a1', 'ld06', 'ust10lx', 'tim571')
"""The rotating lidars of the de-skew grid (:mod:`laser_odom.core.simulation.sensors`)."""

GRID_MOTIONS = ('gentle', 'spin', 'aggressive')
"""The motion profiles of the de-skew grid."""

GRID_DURATION = 60.0
"""Seconds of a grid dataset: 300-900 scans at 5-15 Hz."""

GRID_DURATIONS = {'ust10lx': 20.0}
"""Shorter grid datasets: the UST-10LX at 40 Hz makes 800 scans in 20 s."""

TURNING = ConstantTwist(v=0.3, w=1.5, start=(1.0, 0.5, 0.0))
"""Turning at 1.5 rad/s at 0.3 m/s (a 0.2 m circle about a free spot of the office)."""

TURNING_SENSORS = ('lds01', 'rplidar_a1')
"""The slow lidars driven :data:`TURNING` in the de-skew grid."""

TURNING_DURATION = 20.0
"""Seconds of a turning dataset: 100-110 scans, almost five turns."""


def deskew_grid() -> dict[str, SensorSpec]:
    """Return the sensor x motion grid, ``sim-SENSOR-MOTION``, and the turning datasets."""
    grid = {f'sim-{sensor}-{motion}': SensorSpec(
        sensor, motion, GRID_DURATIONS.get(sensor, GRID_DURATION))
        for sensor in GRID_SENSORS for motion in GRID_MOTIONS}
    grid.update({f'sim-{sensor}-turning': SensorSpec(sensor, TURNING, TURNING_DURATION)
                 for sensor in TURNING_SENSORS})
    return grid


WORLD_SENSORS = {'campus': 'tim571', 'hall': 'rplidar_a1'}
"""The lidar of each world of the ``worlds`` grid: outdoors a 25 m, 270 deg scanner (the
SICK TiM571's figures), in the hall a 12 m one (the RPLIDAR A1) whose range the walls
are beyond in the middle aisle."""

WORLD_RATE = 5.0
"""Scan rate [Hz] of the ``worlds`` grid: at the ``fast`` profile's 1 m/s and 1.5 rad/s,
0.2 m and up to 17 deg between scans."""

WORLD_SPEEDS = {'slow': 'gentle', 'fast': 'fast'}
"""The ``worlds`` grid's speeds and the motion profiles that drive them."""

WORLD_DURATIONS = {('campus', 'slow'): 240.0}
"""Seconds of a ``worlds`` dataset where not :data:`WORLD_DURATION`: the slow campus run
needs 240 s for its 104 m, two segments of the 50 m drift."""

WORLD_DURATION = 120.0
"""Seconds of a ``worlds`` dataset: 600 scans, 52 m slow and 119 m fast."""

WORLD_SEEDS = (1, 2, 3)
"""Seeds of the ``worlds`` grid (range noise and wheel odometry; the path is the same)."""


def worlds_grid() -> dict[str, SensorSpec]:
    """Return the campus and hall runs, ``sim-WORLD-SPEED-sSEED``, at 5 Hz."""
    return {f'sim-{world}-{speed}-s{seed}': SensorSpec(
        sensor, motion, WORLD_DURATIONS.get((world, speed), WORLD_DURATION), world, seed,
        WORLD_RATE)
        for world, sensor in WORLD_SENSORS.items() for speed, motion in WORLD_SPEEDS.items()
        for seed in WORLD_SEEDS}


GRIDS: dict[str, dict[str, SensorSpec]] = {'deskew': deskew_grid(), 'worlds': worlds_grid()}
"""Groups of datasets a benchmark run leaves out unless asked (``--grid``): ``deskew``
is the rotating lidars driven ``gentle``, ``spin`` and ``aggressive`` and turning at
1.5 rad/s, to be run with de-skewing on and off; ``worlds`` is the outdoor campus and
the convention hall (:mod:`laser_odom.core.simulation.world`), slow and fast, at 5 Hz,
three seeds each."""


@dataclass
class BenchRow:
    """One benchmark row: a dataset x matcher x prior and its figures."""

    dataset: str
    matcher: str
    prior: str
    deskew: str
    """The pipeline's ``deskew`` setting (``-`` for the wheel odometry row)."""
    beams: int
    scans: int
    steps: int
    rpe_trans_mean: float
    rpe_trans_rms: float
    rpe_rot_mean: float
    rpe_rot_rms: float
    ate: float
    failed: int | None
    """Failed steps; None (``n/a``) when the dataset has no reference to score against."""
    rejected: int
    median_ms: float
    p95_ms: float
    nees_1: float = math.nan
    """Mean NEES (about 3 when the covariance is honest, 3 dof) of the relative pose
    over windows of 1 step between referenced scans
    (:mod:`laser_odom.core.evaluation.consistency`); NaN (``null``) without a reference
    or covariances, and in files written before."""
    nees_10: float = math.nan
    """The same over windows of 10 steps."""
    nees_100: float = math.nan
    """The same over windows of 100 steps."""
    nees_integrated: float = math.nan
    """Mean NEES of the published pose and covariance, relative to the first referenced
    scan."""
    reference_noise_m: float = 0.0
    """Noise of each reference pose that the NEES accounts for, in x and in y [m]."""
    reference_noise_deg: float = 0.0
    """Noise of each reference pose that the NEES accounts for, in heading [deg]."""
    announced: int | None = None
    """Failed steps whose published step covariance covered them (NEES within the
    99.9 % bound, :mod:`laser_odom.core.evaluation.consistency`); None without a reference."""
    silent: int | None = None
    """Failed steps it did not cover: a filter fusing the odometry takes them as truth."""
    reference: str = 'scan'
    """What each scan was matched against: the pipeline's ``reference`` setting
    (``scan`` or ``local_map``; ``-`` for the wheel odometry row)."""
    drift_trans: float = math.nan
    """Translational drift over segments of :attr:`drift_length` metres of path, in
    percent of the path (KITTI style, :func:`.metrics.segment_drift`); NaN without a
    reference."""
    drift_rot: float = math.nan
    """Rotational drift over the same segments [deg/m]."""
    drift_length: float = math.nan
    """Segment length of the drift [m]: 50, or shorter on a short log."""
    copy: int = 0
    """Which copy of the dataset ran: 0 the dataset as received, k > 0 the copy with
    1 mm of range noise drawn from seed k (``laser_odom_bench --perturb``)."""

    def as_dict(self) -> dict:
        """Return the row as a JSON-friendly dict."""
        return asdict(self)

    @classmethod
    def from_dict(cls, values: dict) -> BenchRow:
        """Return a row from its ``as_dict`` (a ``--json`` row).

        Fields it lacks (a file written before they existed: the NEES) take their
        defaults; unknown keys are ignored.
        """
        known = {f.name for f in fields(cls)}
        return cls(**{key: value for key, value in values.items() if key in known})


Accuracy = tuple[int, float, float, float, float, float, int | None]
"""Steps, RPE translation mean and RMS, rotation mean and RMS, ATE, failed steps."""


def _accuracy(estimate: Trajectory, reference: Trajectory) -> Accuracy:
    """Score against the reference; without one (a user's bag) 0 steps, NaN, failed None."""
    if len(reference) == 0:
        nan = float('nan')
        return 0, nan, nan, nan, nan, nan, None
    errors = evaluate(estimate, reference)
    return (errors.steps, errors.rpe_trans_mean, errors.rpe_trans_rms, errors.rpe_rot_mean,
            errors.rpe_rot_rms, errors.ate_rms, errors.failed_steps)


def _row(dataset: Dataset, matcher: str, prior: str, deskew: str, estimate: Trajectory,
         times: np.ndarray, rejected: int, consistency: Consistency | None = None,
         noise: ReferenceNoise = NO_REFERENCE_NOISE,
         failures: FailedSteps | None = None, reference: str = 'scan') -> BenchRow:
    """Score an estimated trajectory against the dataset's reference (if it has one).

    ``reference`` is what the scans were matched against (the row key).
    """
    timed = times[WARMUP_SCANS:] if times.size > 2 * WARMUP_SCANS else times
    median_ms = float(np.median(timed) * 1e3) if timed.size else float('nan')
    p95_ms = float(np.percentile(timed, 95) * 1e3) if timed.size else float('nan')
    beams = len(dataset.scans[0].ranges) if dataset.scans else 0
    row = BenchRow(dataset.name, matcher, prior, deskew, beams, len(dataset.scans),
                   *_accuracy(estimate, dataset.reference), rejected, median_ms, p95_ms,
                   reference=reference)
    if len(dataset.reference) and len(estimate):
        drift = segment_drift(estimate, dataset.reference)
        row.drift_trans, row.drift_rot = drift.translation, drift.rotation
        row.drift_length = drift.length
    if consistency is not None:
        for name, n in NEES_FIELDS.items():
            setattr(row, name, consistency.windows[n])
        row.nees_integrated = consistency.integrated
        row.reference_noise_m = noise.translation
        row.reference_noise_deg = math.degrees(noise.rotation)
    if failures is not None:
        row.announced, row.silent = failures.announced, failures.silent
    return row


def _consistency(result: RunResult, reference: Trajectory, model: StepErrorModel,
                 noise: ReferenceNoise) -> Consistency | None:
    """Return the NEES of a run against the reference; None without a reference."""
    if len(reference) == 0 or len(result.trajectory) == 0:
        return None
    return run_consistency(result.trajectory, result.pose_covariances,
                           result.step_covariances, result.statuses, reference, model,
                           noise)


def benchmark_run(dataset: Dataset, matcher: str, prior: str = 'constant_velocity',
                  progress: Callable[[int], None] | None = None,
                  config: PipelineConfig | None = None,
                  deskew: str | None = None,
                  reference_noise: ReferenceNoise = NO_REFERENCE_NOISE,
                  reference: str | None = None) -> BenchRow:
    """Run the pipeline with ``matcher`` and bench ``prior`` over a dataset and score it.

    ``deskew`` and ``reference`` (``scan``, ``local_map``) override the
    configuration's settings of those names when given.
    ``reference_noise`` is the noise of each reference pose that the NEES accounts
    for (:data:`REAL_REFERENCE_NOISE` for a real log; none for a simulated one).
    """
    if config is None:
        config = PipelineConfig(matcher=matcher, matcher_config=default_config(matcher))
    config.motion.prior = BENCH_PRIORS[prior]
    if deskew is not None:
        if deskew not in DESKEW_MODES:
            raise ValueError(f'unknown deskew value {deskew!r}; valid: '
                             f'{", ".join(DESKEW_MODES)}')
        config.scan.deskew = deskew
    if reference is not None:
        if reference not in REFERENCE_MODES:
            raise ValueError(f'unknown reference value {reference!r}; valid: '
                             f'{", ".join(REFERENCE_MODES)}')
        config.local_map.reference = reference
    pipeline = OdometryPipeline(config, events=EventLog(lambda message: None))
    feed = None
    if prior == 'odom':
        feed = PriorFeed('odom', PriorConfig(), odometry=dataset.odometry)
    result = run_pipeline(pipeline, dataset.scans, priors=feed, progress=progress)
    model = (StepErrorModel.of_map(pipeline.matcher.config)
             if pipeline.map_registrar is not None
             else StepErrorModel.of(pipeline.matcher.config))
    consistency = _consistency(result, dataset.reference, model, reference_noise)
    failures = None if consistency is None else failed_steps(
        result.trajectory, result.step_covariances, dataset.reference, reference_noise)
    return _row(dataset, matcher, prior, config.scan.deskew, result.trajectory,
                result.processing_times, result.counters['rejected'], consistency,
                reference_noise, failures, config.local_map.reference)


def simulated_scanner(config: PipelineConfig) -> PipelineConfig:
    """Return ``config`` for the simulated scanner: exact but for its noise.

    The heading walk of a real scanner (``covariance_heading_walk`` and
    ``map_covariance_heading_walk``, fitted to the real logs;
    :mod:`laser_odom.core.uncertainty.pose_uncertainty`) is not there.
    """
    matcher_config = dataclasses.replace(config.resolved_matcher_config(),
                                         covariance_heading_walk=0.0,
                                         map_covariance_heading_walk=0.0)
    return dataclasses.replace(config, matcher_config=matcher_config)


def wheel_odometry_trajectory(dataset: Dataset) -> Trajectory:
    """Return raw wheel odometry at the scan stamps, relative to its first pose."""
    stamps, poses = [], []
    origin = None
    for scan in dataset.scans:
        pose = dataset.odometry.interpolate(scan.stamp_ns)
        if pose is None:
            continue
        origin = pose if origin is None else origin
        stamps.append(scan.stamp_ns)
        poses.append(se2.relative(origin, pose))
    return Trajectory(np.array(stamps, dtype=np.int64), np.array(poses).reshape(-1, 3))


def wheel_odometry_row(dataset: Dataset) -> BenchRow:
    """Score raw wheel odometry alone: the do-nothing baseline for every matcher."""
    return _row(dataset, WHEEL_ODOMETRY, 'odom', NOT_APPLICABLE,
                wheel_odometry_trajectory(dataset), np.zeros(0), 0,
                reference=NOT_APPLICABLE)
