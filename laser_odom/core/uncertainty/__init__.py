"""How uncertain a match and the integrated pose are.

``degeneracy`` (the directions of an information matrix too weak to trust),
``evidence`` (a match's covariance grown by what its search surface
shows) and ``pose_uncertainty`` (the integrated pose's covariance when the errors of
consecutive matches are correlated).

May import: ``se2``.
"""
