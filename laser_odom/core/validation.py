"""Scan validation before matching: every rejected scan gets a named reason."""

from __future__ import annotations

from laser_odom.core.config import MountingConfig, ScanConfig
from laser_odom.core.scan import LaserScan, scan_to_points, ScanPoints


class ScanValidator:
    """Checks a scan's fields and converts it to base-frame points."""

    def __init__(self, scan_config: ScanConfig, mounting: MountingConfig) -> None:
        """Create the validator for the given settings."""
        self.config = scan_config
        self.mounting = mounting.mounting()

    def check(self, scan: LaserScan) -> tuple[ScanPoints | None, str]:
        """Return ``(points, '')`` for a usable scan or ``(None, reason)``."""
        if len(scan.ranges) == 0:
            return None, 'empty_scan'
        points = scan_to_points(scan, self.mounting)
        if len(points) < self.config.min_valid_points:
            return None, 'too_few_points'
        return points, ''
