"""Global search: correlative scan matching over a window, independent of the guess."""

from laser_odom.core.search.correlative import (
    correlative_search, SearchPeak, SearchResult, SearchWindow)

__all__ = ['SearchPeak', 'SearchResult', 'SearchWindow', 'correlative_search']
