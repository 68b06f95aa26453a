"""Compile the scan-matching kernels ahead of the first scan.

The matchers' inner loops are compiled by numba on first use and cached on disk (next
to the package when it is writable, else in the user's cache directory), so only the
first start after an install pays the compilation (tens of seconds on a small
computer); later starts load the cache in about a second. numba compiles one
*specialisation* per combination of argument types (a C-contiguous or a strided array,
an omitted default), and caches each on its own: a setting that sends a kernel other
types than the default run does would compile it again inside the node. So the
install-time warm-up (``laser_odom_warmup``, run by ``make``) is thorough: every matcher
on a short simulated drive with its defaults, then with each other value of every
choice and switch of the pipeline and of the matcher (``global_search: always``,
``prior: odom``, ``deskew: on`` on a sweeping lidar, an upside-down laser, keyframes,
each robust kernel, ...), on a 360-beam and a sweeping scanner. The node's own warm-up
at start runs its matcher's defaults only, which loads the kernels from the cache.

Whether a warm-up compiled anything is read from numba's own cache statistics, not
from how long it took: loading is slow on a busy machine too.
"""

from __future__ import annotations

from dataclasses import dataclass
import sys
import time
from typing import Any, Iterator, Sequence

WARMUP_SECONDS = 0.5
"""Length of the simulated drive that exercises a matcher's kernels [s]."""

SWEEPING_SENSOR = 'lds01'
"""A rotating lidar whose scans carry sweep timing (the de-skewing paths)."""

_WARM: set[str] = set()
"""Matchers whose kernels this process has already run (loaded or compiled)."""

_THOROUGH: set[str] = set()
"""Matchers whose every setting this process has already run."""


@dataclass
class WarmUp:
    """What :func:`warm_up` did: the matchers run, the seconds spent, the cache folder.

    ``compiled`` counts the kernel specialisations numba compiled (not found in its
    cache); 0 means every kernel was loaded.
    """

    matchers: tuple[str, ...]
    seconds: float
    cache_dir: str
    compiled: int = 0
    settings: int = 0
    """How many settings (defaults and variants) were run."""

    def note(self, slow: float) -> str:
        """Return what a node's start says: a compilation always, a load slower than ``slow``.

        numba's statistics tell a compilation (a kernel not in the cache:
        laser_odom_warmup was not run after this install) from a load that was merely
        slow (a busy machine).
        """
        names = ', '.join(self.matchers)
        if self.compiled:
            return (f'compiled {self.compiled} {names} kernel specialisations in '
                    f'{self.seconds:.1f} s: laser_odom_warmup was not run after this install '
                    f'(or the source changed); cached in {self.cache_dir} for later starts')
        if self.seconds > slow:
            return (f'loaded the {names} kernels from the cache in {self.seconds:.1f} s '
                    '(none compiled; the machine is busy)')
        return ''


def kernel_cache_dir() -> str:
    """Return the folder numba caches the compiled kernels in."""
    from laser_odom.core.scan.nearest import k_nearest_by_bearing
    try:
        return str(k_nearest_by_bearing._cache._cache_path)
    except AttributeError:  # numba's internals moved: say where it is configured
        import numba
        return numba.config.CACHE_DIR or '(numba default)'


def kernels() -> dict[str, Any]:
    """Return every compiled kernel (numba dispatcher) of the loaded laser_odom modules."""
    from numba.core.dispatcher import Dispatcher
    found = {}
    for name, module in list(sys.modules.items()):
        if name == 'laser_odom' or name.startswith('laser_odom.'):
            for value in list(vars(module).values()):
                if isinstance(value, Dispatcher):
                    found[f'{value.py_func.__module__}.{value.py_func.__qualname__}'] = value
    return found


def compiled_count() -> int:
    """Return how many kernel specialisations this process compiled (cache misses)."""
    return sum(sum(d.stats.cache_misses.values()) for d in kernels().values())


def specialisations() -> set[tuple[str, str]]:
    """Return ``(kernel, argument types)`` of every specialisation this process has."""
    return {(name, str(signature)) for name, d in kernels().items()
            for signature in d.signatures}


def variants(matcher: str) -> Iterator[dict[str, Any]]:
    """Yield the settings a thorough warm-up runs for ``matcher``, defaults first.

    Every other value of each choice and switch of the pipeline and of the matcher,
    one at a time (node-only settings - frames, TF, diagnostics - never reach a
    kernel), plus keyframes on.
    """
    from laser_odom.core.configuration.node import PriorConfig
    from laser_odom.core.configuration.node import NodeConfig, parameter_specs
    from laser_odom.core.parameters import param_fields
    shell = {f.name for cls in (NodeConfig, PriorConfig) for f in param_fields(cls)}
    yield {}
    for spec in parameter_specs():
        group, _, _ = spec.name.rpartition('.')
        if spec.name == 'matcher' or spec.name in shell or group not in ('', matcher):
            continue
        if spec.info.choices:
            for choice in spec.info.choices:
                if choice != spec.default:
                    yield {spec.name: choice}
        elif isinstance(spec.default, bool):
            yield {spec.name: not spec.default}
    yield {'keyframe_distance': 0.3, 'keyframe_angle': 0.3}


def _drives(thorough: bool) -> list[Any]:
    """Return the short simulated drives to run on: an ideal lidar (and a sweeping one)."""
    from laser_odom.core.simulation import simulate
    drives = [simulate('office', duration=WARMUP_SECONDS, seed=0)]
    if thorough:
        drives.append(simulate('office', duration=2 * WARMUP_SECONDS, seed=0,
                               sensor=SWEEPING_SENSOR))
    return drives


def _run(matcher: str, values: dict[str, Any], drive: Any) -> None:
    """Run the pipeline with ``values`` over one drive, as the node and the replay do."""
    from laser_odom.core.events import EventLog
    from laser_odom.core.pipeline.odometry import OdometryPipeline
    from laser_odom.core.motion.priors import PriorFeed
    from laser_odom.core.pipeline.runner import run_pipeline
    from laser_odom.core.configuration.node import settings_from_params
    settings = settings_from_params({'matcher': matcher, **values})
    pipeline = OdometryPipeline(settings.pipeline, events=EventLog(lambda message: None))
    feed = PriorFeed(settings.pipeline.motion.prior, settings.priors,
                     odometry=drive.odometry)
    run_pipeline(pipeline, drive.scans, priors=feed)


def warm_up(matchers: Sequence[str] | None = None, thorough: bool = False) -> WarmUp:
    """Run each matcher's pipeline on a short simulated drive, compiling its kernels.

    ``thorough`` (the install-time warm-up) also runs every setting of
    :func:`variants` on an ideal and a sweeping lidar, so that no setting the node can
    be given compiles a kernel later. A matcher this process already warmed up (as
    thoroughly) is skipped: its kernels are loaded.
    """
    from laser_odom.core.matchers import matcher_names
    names = tuple(matchers) if matchers else tuple(matcher_names())
    start = time.perf_counter()
    compiled_before = compiled_count()
    done = _THOROUGH if thorough else _WARM
    cold = [name for name in names if name not in done]
    drives = _drives(thorough) if cold else []
    runs = 0
    for name in cold:
        for values in (variants(name) if thorough else [{}]):
            for drive in drives:
                _run(name, values, drive)
                runs += 1
        done.add(name)
        _WARM.add(name)
    return WarmUp(names, time.perf_counter() - start, kernel_cache_dir(),
                  compiled_count() - compiled_before, runs)
