"""Global search: correlative scan matching over a window, independent of the guess.

``grid`` (likelihood and bound grids), ``tree`` (branch and bound) and ``correlative``
(the search over a window, Olson 2009).

May import: ``se2``, ``scan``.
"""

from laser_odom.core.search.correlative import (
    correlative_search, SearchPeak, SearchResult, SearchWindow)

__all__ = ['SearchPeak', 'SearchResult', 'SearchWindow', 'correlative_search']
