"""The local map: the reference of recent scans that scan matching drifts least against.

``cells`` (a 2D hash of cells holding the moments of their points, compiled), ``view``
(what the laser sees of the map from a pose, what a scan shows is gone), ``map`` (the
map itself) and ``reference`` (the map as the pipeline's reference: which scans join it,
what a match sees).

May import: ``se2``, ``scan``, ``matchers``, ``configuration``.
"""
