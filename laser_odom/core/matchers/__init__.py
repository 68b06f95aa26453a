"""Scan matchers: one interface (:class:`ScanMatcher`), one registry by name.

Importing this package registers every matcher module listed below.
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
