"""Configuration: every parameter of the odometry, declared once with its default and range.

``pipeline`` holds the pipeline's configuration, one group per concern (scan, mounting,
motion, acceptance, search, keyframes, local map: :class:`PipelineConfig`); ``node``
holds the node's settings - every parameter it has (the pipeline's, the priors'
buffers, the ROS shell's own) and the one set of rules that judges them. How a single
parameter is declared and checked is :mod:`laser_odom.core.parameters` (below the
matchers, which declare theirs with it; each matcher's configuration lives with it).

May import: ``se2``, ``parameters``, ``scan``, ``search``, ``matchers``.
"""
