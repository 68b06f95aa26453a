"""Dataset importers (ROS-free): CARMEN logs and MATLAB scan files to :class:`Dataset`.

Use :func:`load_dataset` for any file and :func:`discover_datasets` to find the real
benchmark logs (``mit-csail``, ``fr079``, ``intel``, ``intel-kf``) under a data
directory. Loaders
raise :class:`DatasetError` (a ``ValueError``) with a ``file:line: what is wrong``
message; malformed lines are skipped and logged on the ``laser_odom.core.datasets``
logger unless ``strict=True``.

May import: ``se2``, ``scan``, ``trajectory``.
"""

from laser_odom.core.datasets.carmen import load_carmen
from laser_odom.core.datasets.common import DatasetError
from laser_odom.core.datasets.loader import (
    dataset_format, dataset_name, discover_datasets, FAST_DATASETS, KNOWN_DATASETS,
    load_dataset, SUBSAMPLED_DATASETS, subsampled_datasets)
from laser_odom.core.datasets.matlab import load_mat
from laser_odom.core.datasets.variants import (
    as_received, DerivedSpec, RANGE_NOISE_M, restamped, with_range_noise)

__all__ = ['DatasetError', 'DerivedSpec', 'FAST_DATASETS', 'KNOWN_DATASETS', 'RANGE_NOISE_M',
           'as_received', 'restamped', 'with_range_noise', 'SUBSAMPLED_DATASETS', 'dataset_format',
           'dataset_name', 'discover_datasets', 'load_carmen', 'load_dataset', 'load_mat',
           'subsampled_datasets']
