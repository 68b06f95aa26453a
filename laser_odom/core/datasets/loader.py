"""One entry point for every dataset format: :func:`load_dataset` and :func:`discover_datasets`.

The format is chosen from the file name: ``.mat`` is a MATLAB scan file
(:mod:`~laser_odom.core.datasets.matlab`), ``.clf`` / ``.log`` (optionally ``.gz``) a
CARMEN log (:mod:`~laser_odom.core.datasets.carmen`). A ``reference_keyframes.txt`` beside
the file is joined as the reference when its ``# columns:`` header says it indexes that
kind of file (``raw_scan_index`` for CARMEN logs, ``mat_row_index`` for .mat files), so
``intel/intel-corrected.log.gz`` (the Intel keyframe log, ``intel-kf``) does not pick
up the keyframes meant for ``intel/scan_intel.mat``; a GMapping-corrected log keeps its
own per-scan reference. Derived datasets (``fr079/5``: every 5th scan;
``fr079/5-fast``: the same re-stamped 0.1 s apart) come from a loaded one through
:class:`~laser_odom.core.datasets.variants.DerivedSpec`.
"""

from __future__ import annotations

from pathlib import Path

from laser_odom.core.datasets.carmen import load_carmen
from laser_odom.core.datasets.common import DatasetError
from laser_odom.core.datasets.keyframes import KEYFRAMES_FILE, keyframes_index_kind
from laser_odom.core.datasets.matlab import load_mat
from laser_odom.core.datasets.variants import DerivedSpec
from laser_odom.core.trajectory import Dataset

#: The real benchmark datasets: name -> path under the data directory. The ccny bag has
#: no reference, so it is a bag-reading smoke test, not a benchmark dataset.
KNOWN_DATASETS: dict[str, str] = {
    'mit-csail': 'mit-csail/mit-csail.clf',
    'fr079': 'fr079/freiburg-079-corrected.log.gz',
    'intel': 'intel/scan_intel.mat',
    'intel-kf': 'intel/intel-corrected.log.gz',
}
#: Large-motion datasets derived from a known one (``name: DerivedSpec``): every k-th
#: scan (fr079's scans then lie 0.5 m / 10 deg (k = 5), 1 m / 19 deg (k = 10, 1-2 s) or
#: 2 m / 38 deg apart (k = 20, 2-5 s; up to 2.3 m and 166 deg)), and the "fast robot"
#: datasets: the same scans (intel-kf: its keyframes, 0.4-4 s apart) re-stamped 0.1 s
#: apart, what a robot 5-10x faster records at 10 Hz, so that the constant-velocity
#: prediction is trusted on large steps.
FAST_PERIOD = 0.1
"""Seconds between the scans of a re-stamped "fast robot" dataset (10 Hz)."""

SUBSAMPLED_DATASETS: dict[str, DerivedSpec] = {
    'fr079/5': DerivedSpec('fr079', 5),
    'fr079/10': DerivedSpec('fr079', 10),
    'fr079/20': DerivedSpec('fr079', 20),
    'fr079/5-fast': DerivedSpec('fr079', 5, FAST_PERIOD),
    'fr079/10-fast': DerivedSpec('fr079', 10, FAST_PERIOD),
    'intel-kf-fast': DerivedSpec('intel-kf', 1, FAST_PERIOD),
}
FAST_DATASETS = tuple(name for name, spec in SUBSAMPLED_DATASETS.items() if spec.period)
"""The re-stamped "fast robot" datasets."""
CARMEN_SUFFIXES = ('.clf', '.log')
MAT_SUFFIXES = ('.mat',)
_KEYFRAME_KINDS = {'carmen': 'raw_scan_index', 'mat': 'mat_row_index'}


def dataset_format(path: Path | str) -> str:
    """Return ``'carmen'`` or ``'mat'`` for a file name, or raise :class:`DatasetError`."""
    name = Path(path).name.lower()
    if name.endswith('.gz'):
        name = name[:-3]
    if name.endswith(MAT_SUFFIXES):
        return 'mat'
    if name.endswith(CARMEN_SUFFIXES):
        return 'carmen'
    raise DatasetError(f'{path}: unknown dataset format (expected .clf, .log, .log.gz '
                       'or .mat)')


def dataset_name(path: Path | str) -> str:
    """Return the benchmark name of a known dataset file, else the file name sans suffixes."""
    path = Path(path)
    for name, relative in KNOWN_DATASETS.items():
        if path.name == Path(relative).name:
            return name
    stem = path.name[:-3] if path.name.lower().endswith('.gz') else path.name
    return Path(stem).stem or path.name


def find_keyframes(path: Path | str, kind: str) -> Path | None:
    """Return the ``reference_keyframes.txt`` beside ``path`` if it indexes this kind of file."""
    candidate = Path(path).parent / KEYFRAMES_FILE
    if not candidate.is_file():
        return None
    header = keyframes_index_kind(candidate)
    return candidate if header in (None, _KEYFRAME_KINDS[kind]) else None


def load_dataset(path: Path | str, name: str | None = None,
                 keyframes: Path | str | None = None, strict: bool = False) -> Dataset:
    """Load any supported dataset file into a :class:`Dataset`.

    ``keyframes`` overrides the ``reference_keyframes.txt`` picked up beside the file;
    ``strict`` makes a malformed line an error instead of a skipped line with a logged
    warning. Raises :class:`DatasetError` (a ``ValueError``) with a one-line message for a
    missing, unreadable or unusable file.
    """
    path = Path(path)
    if not path.exists():
        raise DatasetError(f'{path}: no such file')
    if path.is_dir():
        raise DatasetError(f'{path}: is a directory, expected a dataset file')
    kind = dataset_format(path)
    if keyframes is None:
        keyframes = find_keyframes(path, kind)
    elif not Path(keyframes).is_file():
        raise DatasetError(f'{keyframes}: no such file')
    loader = load_mat if kind == 'mat' else load_carmen
    return loader(path, name=name or dataset_name(path), keyframes=keyframes, strict=strict)


def subsampled_datasets(found: dict[str, Path]) -> dict[str, DerivedSpec]:
    """Return the derived datasets whose base dataset is among ``found``."""
    return {name: spec for name, spec in SUBSAMPLED_DATASETS.items() if spec.base in found}


def discover_datasets(data_dir: Path | str) -> dict[str, Path]:
    """Return the known real datasets present under ``data_dir`` (name -> file path)."""
    root = Path(data_dir)
    found = {name: root / relative for name, relative in KNOWN_DATASETS.items()}
    return {name: path for name, path in found.items() if path.is_file()}
