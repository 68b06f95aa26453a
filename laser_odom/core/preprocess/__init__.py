"""The scan's first steps: validation (every rejected scan gets a named reason) and de-skewing.

``validation`` (skip or repair a scan before it is matched, with a reason counted) and
``deskew`` (a scan swept while the robot moved, moved to the instant of its stamp).

May import: ``se2``, ``events``, ``scan``, ``configuration``.
"""
