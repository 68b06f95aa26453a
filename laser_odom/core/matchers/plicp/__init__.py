"""Point-to-line ICP (Censi 2008) with its exact closed-form step.

``matcher`` (:class:`PlicpMatcher`, :class:`PlicpConfig`; importing registers ``plicp``),
``segments`` (the reference scan as segments between beam-order neighbours, the model)
and ``solver`` (the compiled iterations).

May import: the shared parts of ``matchers``, ``se2``, ``parameters``, ``scan``.
"""

from laser_odom.core.matchers.plicp.matcher import PlicpConfig, PlicpMatcher

__all__ = ['PlicpConfig', 'PlicpMatcher']
