"""Point-to-point ICP (Besl & McKay 1992) with the closed-form SVD step.

``matcher`` (:class:`IcpMatcher`, :class:`IcpConfig`; importing registers ``icp``) and
``solver`` (the compiled iterations).

May import: the shared parts of ``matchers``, ``se2``, ``parameters``, ``scan``.
"""

from laser_odom.core.matchers.icp.matcher import IcpConfig, IcpMatcher

__all__ = ['IcpConfig', 'IcpMatcher']
