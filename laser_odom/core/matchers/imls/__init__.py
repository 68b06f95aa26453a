"""IMLS-ICP (Deschaud 2018): point-to-implicit-surface matching of informative points.

``matcher`` (:class:`ImlsMatcher`, :class:`ImlsConfig`; importing registers ``imls``),
``surface`` (the implicit moving-least-squares surface and the informative points, the
model) and ``solver`` (the point-to-plane Gauss-Newton pieces).

May import: the shared parts of ``matchers``, ``se2``, ``parameters``, ``scan``.
"""

from laser_odom.core.matchers.imls.matcher import ImlsConfig, ImlsMatcher

__all__ = ['ImlsConfig', 'ImlsMatcher']
