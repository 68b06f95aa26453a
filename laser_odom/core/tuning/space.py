"""The search space of ``laser_odom_tune``: which parameters, over which values.

Per matcher the space holds the matcher's own parameters and the pipeline settings
that change the trajectory (:data:`PIPELINE_PARAMETERS`). The ranges come from the
declared parameter ranges (:mod:`laser_odom.core.parameters`), narrowed around the
starting value ``v`` (the node's default, or the ``--params-file`` value):

- a floating-point parameter searches ``[v / 4, v * 4]`` clipped to its declared range,
  on a log scale (the lower end is then positive): a factor of 4 each way holds every
  tuned default of the shipped matchers within a factor of 2 of its neighbours, while
  the declared ranges (often 6-12 decades) are limits of validity, not of sense;
- an integer searches ``[ceil(v / 4), v * 4]`` likewise, on a log scale from 1;
- a choice (or a boolean) is categorical over all its choices.

A few settings need their own range (:data:`RANGES`): those whose default is 0
(keyframes off) and the search resolution, whose cost grows with the inverse square.
Not searched: ``covariance_scale`` and the ``covariance_*`` error shares, which calibrate
the published covariance and
must not be traded for accuracy. ``prior`` searches ``none`` and
``constant_velocity``, plus ``odom`` / ``imu`` when every bag has that topic.

No trial crosses an ordered pair (:func:`~laser_odom.core.configuration.node.ordered_pairs`,
such as ``nicp.normal_min_neighbours`` <= ``nicp.normal_neighbours``), which the node
would refuse: a searched parameter below a fixed one has its range cut at that value,
one above a fixed one likewise from below, and of two searched ones the lower is
suggested after the higher, up to its value (:func:`suggest`).

``--space FILE`` (YAML, flat ``nicp.h`` or nested names) overrides ranges:
``name: [low, high]`` for a number, ``name: [choice, ...]`` for a choice; a parameter
not in the default space is added. Every mistake is a :class:`SpaceError` of one line.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
import difflib
import math
from pathlib import Path
from typing import Any, Mapping, Protocol, Sequence

import yaml

from laser_odom.core.configuration.node import ordered_pairs, parameter_specs, ParameterSpec
from laser_odom.core.parameters import flatten, ParamInfo, yaml_word

PIPELINE_PARAMETERS = (
    'prior', 'reference', 'max_correction_linear', 'max_correction_angular', 'min_inlier_ratio',
    'keyframe_distance', 'keyframe_angle', 'global_search', 'global_search_linear',
    'global_search_angular', 'global_search_resolution', 'global_search_candidates',
    'global_search_ambiguity')
"""Pipeline settings searched with every matcher: the prior, what each scan is matched
against (the previous scan or the local map: on a simulated office bag the setting
that mattered most, ATE 0.14 -> 0.01 m), the gates, keyframes and the global search."""

NOT_SEARCHED = ('covariance_scale', 'covariance_shared_scan', 'covariance_bias',
                'covariance_bias_correlation', 'covariance_baseline_falloff',
                'covariance_heading_walk', 'map_covariance_heading_walk',
                'map_covariance_scale', 'map_covariance_shared', 'map_surface_weak_share')
"""Matcher parameters left out: they calibrate the covariance, not the pose; and
``map_surface_weak_share``, off (0) by default for every matcher but nicp (0.05), and a 0
has no scale to search around (a trial drew 0.69, which cuts nearly every correction).
A space file (``--space``) adds any of them."""

RANGES: dict[str, tuple[float, float]] = {
    'keyframe_distance': (0.0, 0.5),
    'keyframe_angle': (0.0, 0.35),
    'global_search_resolution': (0.05, 0.2),
}
"""Ranges the factor-of-4 rule cannot give: keyframes default to 0 (off) and are
searched up to half a metre / 20 deg; a search cell under 5 cm costs 4x per halving."""

FACTOR = 4.0
"""A number is searched from its starting value divided by this to multiplied by it."""

BASE_PRIORS = ('none', 'constant_velocity')
"""Priors every bag supports; ``odom`` and ``imu`` need their topic."""


class SpaceError(ValueError):
    """A search-space override is unusable; ``str(error)`` is one line."""


class Trial(Protocol):
    """The part of ``optuna.trial.Trial`` the space uses (kept Optuna-free here)."""

    def suggest_float(self, name: str, low: float, high: float, *,
                      log: bool = False) -> float: ...  # noqa: D102, E704

    def suggest_int(self, name: str, low: int, high: int, *,
                    log: bool = False) -> int: ...  # noqa: D102, E704

    def suggest_categorical(self, name: str,
                            choices: Sequence[Any]) -> Any: ...  # noqa: D102, E501, E704


@dataclass(frozen=True)
class Dimension:
    """One searched parameter: its node name, kind, range or choices and start value."""

    name: str
    kind: str
    """``float``, ``int`` or ``categorical``."""
    start: Any
    low: float = 0.0
    high: float = 0.0
    log: bool = False
    choices: tuple[Any, ...] = ()
    at_most: tuple[str, ...] = ()
    """Searched parameters this one must not exceed: suggested after them, up to their
    values."""

    def suggest(self, trial: Trial, ceiling: float = math.inf) -> Any:
        """Return the trial's value of this parameter, at most ``ceiling``."""
        if ceiling < self.high:
            return replace(self, high=ceiling, at_most=()).suggest(trial)
        if self.kind == 'categorical':
            return trial.suggest_categorical(self.name, list(self.choices))
        if self.kind == 'int':
            return trial.suggest_int(self.name, int(self.low), int(self.high), log=self.log)
        return trial.suggest_float(self.name, self.low, self.high, log=self.log)

    def contains(self, value: Any) -> bool:
        """Tell whether ``value`` is a point of this dimension."""
        if self.kind == 'categorical':
            return value in self.choices
        return isinstance(value, (int, float)) and self.low <= value <= self.high

    def describe(self) -> str:
        """Return the range as text (``[0.1, 1.6] log``, ``none | odom``)."""
        if self.kind == 'categorical':
            return ' | '.join(str(c) for c in self.choices)
        return f'[{self.low:g}, {self.high:g}]' + (' log' if self.log else '')


def _numeric(spec: ParameterSpec, start: float) -> Dimension:
    """Return the default range of a number: :data:`RANGES`, or the factor-of-4 rule."""
    info = spec.info
    is_int = isinstance(spec.default, int)
    declared_low = -math.inf if info.low is None else info.low
    declared_high = math.inf if info.high is None else info.high
    if spec.name in RANGES:
        low, high = RANGES[spec.name]
    elif start > 0:
        low, high = start / FACTOR, start * FACTOR
    else:  # a non-positive start has no factor range: search up to the declared bound
        low, high = declared_low, min(declared_high, 1.0)
    if is_int:
        low, high = math.ceil(low), math.floor(high)
    low, high = max(low, declared_low), min(high, declared_high)
    log = low > 0 and spec.name not in RANGES
    return Dimension(spec.name, 'int' if is_int else 'float', start, low, high, log)


def _dimension(spec: ParameterSpec, start: Any) -> Dimension:
    """Return the default dimension of one parameter."""
    if isinstance(spec.default, bool):
        return Dimension(spec.name, 'categorical', start, choices=(True, False))
    if isinstance(spec.default, str):
        return Dimension(spec.name, 'categorical', start, choices=tuple(spec.info.choices or ()))
    return _numeric(spec, start)


def searched_names(matcher: str, specs: Mapping[str, ParameterSpec]) -> list[str]:
    """Return the parameters searched by default for ``matcher``, pipeline first."""
    own = [name for name in specs if name.startswith(matcher + '.')
           and name.split('.', 1)[1] not in NOT_SEARCHED]
    return list(PIPELINE_PARAMETERS) + own


def matcher_space(matcher: str, start: Mapping[str, Any], priors: Sequence[str],
                  overrides: Mapping[str, list[Any]] | None = None) -> list[Dimension]:
    """Return the search space of ``matcher`` around the ``start`` values.

    ``start`` holds values that differ from the node's defaults (a params file); the
    node's default is the start of every other parameter. ``priors`` are the choices of
    ``prior`` the bags support. ``overrides`` (from :func:`read_space_file`) replace
    or add ranges; an override of another matcher's parameter is ignored here.
    """
    specs = {spec.name: spec for spec in parameter_specs()}
    dimensions = {}
    for name in searched_names(matcher, specs):
        dimensions[name] = _dimension(specs[name], start.get(name, specs[name].default))
    dimensions['prior'] = replace(dimensions['prior'], choices=tuple(priors))
    for name, values in (overrides or {}).items():
        if '.' in name and not name.startswith(matcher + '.'):
            continue
        dimension = dimensions.get(name) or _dimension(specs[name],
                                                       start.get(name, specs[name].default))
        dimensions[name] = _override(dimension, specs[name].info, values)
    if not set(dimensions['prior'].choices) <= set(priors):
        missing = sorted(set(dimensions['prior'].choices) - set(priors))
        raise SpaceError(f'prior {", ".join(missing)}: not every bag has the topic for it')
    _keep_order(dimensions, {name: start.get(name, spec.default) for name, spec in specs.items()})
    return list(dimensions.values())


def _keep_order(dimensions: dict[str, Dimension], fixed: Mapping[str, Any]) -> None:
    """Cut the ranges so that no trial crosses an ordered pair; SpaceError if none can.

    ``fixed`` holds the value every parameter has when it is not searched.
    """
    for low, high in ordered_pairs():
        lower, upper = dimensions.get(low), dimensions.get(high)
        if lower is None and upper is None:
            continue
        if lower is not None and upper is not None:
            upper = replace(upper, low=max(upper.low, lower.low))
            lower = replace(lower, at_most=lower.at_most + (high,))
        elif lower is not None:
            lower = replace(lower, high=min(lower.high, fixed[high]))
        else:
            upper = replace(upper, low=max(upper.low, fixed[low]))
        for dimension in (lower, upper):
            if dimension is None:
                continue
            if dimension.low > dimension.high:
                raise SpaceError(f'--space {dimension.name}: no value left in its range with '
                                 f'{low} <= {high} (the node refuses a minimum above its '
                                 'maximum)')
            dimensions[dimension.name] = replace(
                dimension, log=dimension.log and dimension.low > 0)


def _override(dimension: Dimension, info: ParamInfo, values: list[Any]) -> Dimension:
    """Return ``dimension`` with a ``--space`` range or choice list applied."""
    name = dimension.name
    if dimension.kind == 'categorical':
        allowed = dimension.choices if name != 'prior' else tuple(info.choices or ())
        values = [yaml_word(v, info) for v in values]  # an unquoted off is 'off'
        bad = [v for v in values if v not in allowed]
        if not values:
            raise SpaceError(f'--space {name}: empty choice list; give at least one of '
                             f'{", ".join(str(c) for c in allowed)}')
        if bad:
            raise SpaceError(f'--space {name}: {bad[0]!r} is not one of '
                             f'{", ".join(str(c) for c in allowed)}')
        return replace(dimension, choices=tuple(dict.fromkeys(values)))
    if len(values) != 2 or not all(isinstance(v, (int, float)) and not isinstance(v, bool)
                                   for v in values):
        raise SpaceError(f'--space {name}: expected [low, high], got {values!r}')
    low, high = float(values[0]), float(values[1])
    if not low <= high:
        raise SpaceError(f'--space {name}: empty range [{low:g}, {high:g}] (low > high)')
    if (info.low is not None and low < info.low) or (info.high is not None and high > info.high):
        raise SpaceError(f'--space {name}: [{low:g}, {high:g}] leaves the declared range '
                         f'[{info.low:g}, {info.high:g}]')
    if dimension.kind == 'int':
        if math.ceil(low) > math.floor(high):
            raise SpaceError(f'--space {name}: no integer in [{low:g}, {high:g}]')
        low, high = math.ceil(low), math.floor(high)
    return replace(dimension, low=low, high=high, log=dimension.log and low > 0)


def read_space_file(path: str | Path, matchers: Sequence[str]) -> dict[str, list[Any]]:
    """Read a ``--space`` YAML file: ``name: [low, high]`` or ``name: [choice, ...]``.

    Names are the node's (``min_inlier_ratio``, ``nicp.max_iterations``), flat or
    nested (``nicp: {max_iterations: [20, 80]}``). Raises :class:`SpaceError`.
    """
    try:
        document = yaml.safe_load(Path(path).read_text())
        flat = flatten(document or {}) if isinstance(document or {}, Mapping) else None
    except (OSError, UnicodeDecodeError) as err:
        raise SpaceError(f'cannot read --space file {path}: {err}') from None
    except yaml.YAMLError as err:
        raise SpaceError(f'--space file {path} is not valid: '
                         f'{str(err).splitlines()[0]}') from None
    if flat is None:
        raise SpaceError(f'--space file {path}: expected "name: [low, high]" lines')
    specs = {spec.name: spec for spec in parameter_specs()}
    overrides = {}
    for name, values in flat.items():
        spec = specs.get(name)
        if name == 'matcher':
            raise SpaceError(f'--space {path}: choose matchers with --matchers, not "matcher"')
        if spec is None or spec.info.read_only:
            close = difflib.get_close_matches(name, list(specs), n=1, cutoff=0.8)
            hint = f' (did you mean {close[0]!r}?)' if close else ''
            raise SpaceError(f'--space {path}: {name!r} is not a tunable parameter{hint}')
        if '.' in name and name.split('.', 1)[0] not in matchers:
            continue
        fixed = isinstance(values, (int, float)) and not isinstance(spec.default, (bool, str))
        overrides[name] = values if isinstance(values, list) else (
            [values, values] if fixed else [values])
    return overrides


def start_values(dimensions: Sequence[Dimension]) -> dict[str, Any]:
    """Return the starting point of a space that lies in it (Optuna's enqueued trial 0).

    A start value that a ``--space`` override excludes is left out: the default trial
    still runs with it (:func:`suggest`), but it is no point of the searched space.
    """
    return {d.name: d.start for d in dimensions if d.contains(d.start)}


def suggest(dimensions: Sequence[Dimension], trial: Trial,
            default: bool = False) -> dict[str, Any]:
    """Return one trial's values of every dimension (the start values for ``default``).

    A dimension with ``at_most`` is suggested after those, up to their values (of two
    searched parameters of an ordered pair, the lower one), so no trial crosses a pair.
    """
    values: dict[str, Any] = {}
    for d in sorted(dimensions, key=lambda d: bool(d.at_most)):  # stable: space order
        if default and not d.contains(d.start):
            values[d.name] = d.start
            continue
        ceiling = min((values[h] for h in d.at_most), default=math.inf)
        values[d.name] = d.suggest(trial, ceiling)
    return {d.name: values[d.name] for d in dimensions}
