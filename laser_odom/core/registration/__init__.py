"""Registration: the match from the prediction, the global search that recovers it, its judging.

``registrar`` (the matcher from the prediction, the global search when it fails or
cannot be trusted), ``usual`` (how accepted matches usually fit), ``doubt`` (when a
trusted prediction is checked against the global search), ``recovery`` (search,
refine the peaks, choose by the fit), ``rejection`` (the rules a match is rejected
by), ``acceptance`` (accept, correct for ambiguity and degeneracy, or reject),
``map_registrar`` (registration against the local map, the previous scan as the
second opinion), ``map_judging`` (the tests it decides by) and ``local_map`` (the
map: cells, ray-cast view, which scans join it).

May import: ``se2``, ``events``, ``parameters``, ``scan``, ``uncertainty``, ``search``,
``matchers``, ``configuration``, ``motion``.
"""
