"""``laser_odom_warmup``: compile the scan-matching kernels now, not at the first scan.

numba compiles the matchers' kernels on first use and caches them on disk; after an
install (or an upgrade) that takes tens of seconds to minutes once. ``make`` runs this
after installing; on a colcon install, run it once (``ros2 run laser_odom
laser_odom_warmup``). It runs every matcher with each setting that can send its kernels
other argument types (:func:`laser_odom.core.pipeline.warmup.variants`), so that no setting
compiles a kernel inside the node later; a second run only loads them and says so.
"""

from __future__ import annotations

import argparse
import sys

from laser_odom.core.matchers import matcher_names
from laser_odom.core.pipeline.warmup import warm_up

PROG = 'laser_odom_warmup'


def main(argv: list[str] | None = None) -> int:
    """Compile the kernels of the given matchers (default: all); return the exit code."""
    parser = argparse.ArgumentParser(
        prog=PROG, description='Compile and cache the scan-matching kernels of the '
        'matchers, so that no start pays for it at its first scan.')
    parser.add_argument('matchers', nargs='*', metavar='MATCHER',
                        help=f'matchers ({", ".join(matcher_names())}; default: all)')
    args = parser.parse_args(argv)
    unknown = [name for name in args.matchers if name not in matcher_names()]
    if unknown:
        parser.error(f'unknown matcher {unknown[0]!r}; valid: {", ".join(matcher_names())}')
    done = warm_up(args.matchers or None, thorough=True)
    how = (f'compiled {done.compiled} kernel specialisations' if done.compiled
           else 'every kernel loaded from the cache, none compiled')
    print(f'{PROG}: kernels of {", ".join(done.matchers)} ready in {done.seconds:.1f} s: '
          f'{done.settings} settings run, {how} (cache: {done.cache_dir})')
    return 0


if __name__ == '__main__':
    sys.exit(main())
