"""Evaluation: how good a run is, against a reference or without one, and the benchmark.

``metrics`` (ATE, RPE, segment drift), ``coverage`` (how much of a run a reference
covers), ``map_quality`` (reference-free: how sharp a map the poses make),
``consistency`` (NEES: is the published covariance honest?) and ``benchmark`` (a matcher
scored on a dataset).

May import: every layer below it (``pipeline`` and down).
"""
