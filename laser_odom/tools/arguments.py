"""Command-line value types shared by the tools, so a bad value reads the same everywhere."""

from __future__ import annotations

import argparse
import math
from typing import Callable


def number_in(kind: type, low: float, high: float, low_open: bool = False,
              what: str = 'value') -> Callable[[str], float]:
    """Return an argparse type that parses ``kind`` (int or float) in ``[low, high]``.

    ``low_open`` makes the range ``(low, high]``; NaN and infinity are out of range.
    The error names the value and the range in one line.
    """
    def parse(text: str) -> float:
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f'{text!r} is not a valid {what}') from None
        if not math.isfinite(value) or value < low or value > high or (
                low_open and value == low):
            bracket = '(' if low_open else '['
            raise argparse.ArgumentTypeError(
                f'{text} is outside {bracket}{low:g}, {high:g}]')
        return value
    return parse
