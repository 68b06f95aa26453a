"""Motion: the prediction each match starts from, and the motion priors.

``model`` (the constant-velocity prediction, or the external prior's), ``priors``
(wheel odometry and IMU buffered by time) and ``blind_prior`` (what stands in where
the scan is blind: the trusted prediction or the last well-constrained step, with its
measured error).

May import: ``se2``, ``parameters``, ``trajectory``, ``configuration``.
"""
