"""The scan as data: a LaserScan, its base-frame points, neighbours by bearing, normals.

``laser_scan`` (LaserScan, LaserMounting, ScanPoints with a per-scan cache, conversion
and densifying), ``nearest`` (exact gated 1- and k-nearest search by bearing, compiled)
and ``normals`` (normals and curvature from the local covariance).

May import: ``se2``.
"""
