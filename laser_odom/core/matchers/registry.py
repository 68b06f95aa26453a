"""Matchers by name: the node's ``matcher`` parameter and the tools' ``--matcher``."""

from __future__ import annotations

from typing import Any, Mapping, TypeVar

from laser_odom.core.matchers.base import MatcherConfig, ScanMatcher
from laser_odom.core.parameters import replace_checked

_MATCHERS: dict[str, type[ScanMatcher]] = {}

MatcherT = TypeVar('MatcherT', bound=type[ScanMatcher])


class UnknownMatcherError(ValueError):
    """The requested matcher name is not registered."""


def register(cls: MatcherT) -> MatcherT:
    """Class decorator that makes a matcher available by its ``name``."""
    _MATCHERS[cls.name] = cls
    return cls


def matcher_names() -> list[str]:
    """Return the registered matcher names, sorted."""
    return sorted(_MATCHERS)


def matcher_class(name: str) -> type[ScanMatcher]:
    """Return the matcher class registered as ``name``."""
    try:
        return _MATCHERS[name]
    except KeyError:
        raise UnknownMatcherError(
            f'unknown matcher {name!r}; valid names: {", ".join(matcher_names())}') from None


def default_config(name: str) -> MatcherConfig:
    """Return the tuned default configuration of a matcher."""
    return matcher_class(name).config_type()


def create_matcher(name: str, overrides: Mapping[str, Any] | None = None) -> ScanMatcher:
    """Create a matcher by name, with validated parameter overrides."""
    cls = matcher_class(name)
    config = replace_checked(cls.config_type(), overrides or {}, prefix=f'{name}.')
    return cls(config)
