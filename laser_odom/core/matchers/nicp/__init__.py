"""NICP (Serafin & Grisetti 2015): normal-based ICP on extended points.

``matcher`` (:class:`NicpMatcher`, :class:`NicpConfig`; importing registers ``nicp``),
``surface`` (per-scan normals, curvature and information blocks), ``model`` (the error
model: pair rules and normal equations) and ``solver`` (the compiled Gauss-Newton).

May import: the shared parts of ``matchers``, ``se2``, ``parameters``, ``scan``,
``uncertainty``.
"""

from laser_odom.core.matchers.nicp.matcher import NicpConfig, NicpMatcher

__all__ = ['NicpConfig', 'NicpMatcher']
