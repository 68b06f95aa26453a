"""The odometry pipeline on top: one scan's path, and what drives it.

``odometry`` (:class:`OdometryPipeline`: validate, predict, register, judge, integrate),
``reconfigure`` (new settings from the next scan on), ``estimate`` (what it returns per
scan and the names of what it counts), ``announce`` (the counted, throttled lines that
say why), ``runner`` (the pipeline over recorded scans: replay, benchmark, tests) and
``warmup`` (compile the kernels before the first scan).

May import: every layer below it (``registration`` and down, ``simulation`` for the
warm-up's drive).
"""
