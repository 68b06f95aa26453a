"""Compile the scan-matching kernels ahead of the first scan.

The matchers' inner loops are compiled by numba on first use and cached on disk (next
to the package when it is writable, else in the user's cache directory), so only the
first start after an install pays the compilation (tens of seconds on a small
computer); later starts load the cache in well under a second. Running a matcher once
on a short simulated drive, before the node subscribes to scans, moves that cost out
of the first scan's latency: the node does it at start, ``make`` after installing.
"""

from __future__ import annotations

from dataclasses import dataclass
import time
from typing import Sequence

WARMUP_SECONDS = 0.5
"""Length of the simulated drive that exercises a matcher's kernels [s]."""

_WARM: set[str] = set()
"""Matchers whose kernels this process has already run (loaded or compiled)."""


@dataclass
class WarmUp:
    """What :func:`warm_up` did: the matchers run, the seconds spent, the cache folder."""

    matchers: tuple[str, ...]
    seconds: float
    cache_dir: str


def kernel_cache_dir() -> str:
    """Return the folder numba caches the compiled kernels in."""
    from laser_odom.core.nearest import k_nearest_by_bearing
    try:
        return str(k_nearest_by_bearing._cache._cache_path)
    except AttributeError:  # numba's internals moved: say where it is configured
        import numba
        return numba.config.CACHE_DIR or '(numba default)'


def warm_up(matchers: Sequence[str] | None = None) -> WarmUp:
    """Run each matcher's pipeline on a short simulated drive, compiling its kernels.

    A matcher this process already warmed up is skipped: its kernels are loaded.
    """
    from laser_odom.core.config import PipelineConfig
    from laser_odom.core.events import EventLog
    from laser_odom.core.matchers import default_config, matcher_names
    from laser_odom.core.pipeline import OdometryPipeline
    from laser_odom.core.simulation import simulate
    names = tuple(matchers) if matchers else tuple(matcher_names())
    start = time.perf_counter()
    cold = [name for name in names if name not in _WARM]
    scans = simulate('office', duration=WARMUP_SECONDS, seed=0).scans if cold else []
    for name in cold:
        pipeline = OdometryPipeline(PipelineConfig(matcher=name,
                                                   matcher_config=default_config(name)),
                                    events=EventLog(lambda message: None))
        for scan in scans:
            pipeline.process(scan)
            pipeline.prepare_next()
        _WARM.add(name)
    return WarmUp(names, time.perf_counter() - start, kernel_cache_dir())
