"""Scan matchers: one interface (:class:`ScanMatcher`), one registry by name.

One package per matcher - ``icp``, ``plicp``, ``nicp``, ``imls`` - each with its
wrapper (``matcher``: the :class:`ScanMatcher` and its configuration), its model and
its compiled ``solver``; beside them the shared parts: the interface (``base``), the
``registry``, ``correspondences``, ``robust`` kernels and ``information`` (information
and covariance of a match). Importing this package registers every matcher listed below.

May import: ``se2``, ``parameters``, ``scan``, ``uncertainty``. A matcher's package
imports the shared parts, never another matcher.
"""

from laser_odom.core.matchers import icp  # noqa: F401  (registers 'icp')
from laser_odom.core.matchers import imls  # noqa: F401  (registers 'imls')
from laser_odom.core.matchers import nicp  # noqa: F401  (registers 'nicp')
from laser_odom.core.matchers import plicp  # noqa: F401  (registers 'plicp')
from laser_odom.core.matchers.base import MatcherConfig, MatchResult, ScanMatcher
from laser_odom.core.matchers.registry import (
    create_matcher, default_config, matcher_class, matcher_names, register,
    UnknownMatcherError)

__all__ = [
    'MatcherConfig', 'MatchResult', 'ScanMatcher', 'create_matcher', 'default_config',
    'matcher_class', 'matcher_names', 'register', 'UnknownMatcherError',
]
