"""Parameter tuning on recorded bags (``laser_odom_tune``).

:mod:`.space` says which parameters are searched over which ranges, :mod:`.objective`
runs one trial over the bags and scores it (against a reference or reference-free),
and :mod:`.study` drives the Optuna studies. Optuna is imported by :mod:`.study` only
when a study runs, so the node and the other tools never need it.

May import: every layer below it (``evaluation`` and down).
"""
