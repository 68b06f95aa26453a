"""Parameters: declared ranges are enforced, flat ROS names map onto grouped configs."""

import pytest

from laser_odom.core.configuration.pipeline import pipeline_config_from_params, PipelineConfig
from laser_odom.core.matchers import create_matcher, matcher_names, UnknownMatcherError
from laser_odom.core.parameters import param_fields, ParameterError


def test_every_parameter_has_description_and_default_in_range():
    config = PipelineConfig()
    groups = [config.scan, config.mounting, config.motion, config.acceptance,
              config.keyframes] + [create_matcher(n).config for n in matcher_names()]
    for group in groups:
        for f in param_fields(type(group)):
            info = f.metadata['param']
            assert info.description.strip(), f.name
            if info.low is not None:
                assert f.default >= info.low, f.name
            if info.high is not None:
                assert f.default <= info.high, f.name
            if info.choices is not None:
                assert f.default in info.choices, f.name


def test_flat_parameters_fill_groups():
    config = pipeline_config_from_params({
        'matcher': 'icp', 'min_inlier_ratio': 0.5, 'laser_x': 0.3, 'prior': 'none',
        'keyframe_distance': 0.2, 'icp.max_iterations': 12})
    assert config.acceptance.min_inlier_ratio == 0.5
    assert config.mounting.laser_x == 0.3
    assert config.motion.prior == 'none'
    assert config.keyframes.keyframe_distance == 0.2
    assert config.resolved_matcher_config().max_iterations == 12


@pytest.mark.parametrize('values, words', [
    ({'min_inlier_ratio': 1.5}, 'above the maximum'),
    ({'icp.max_iterations': 0}, 'below the minimum'),
    ({'prior': 'gps'}, 'not one of'),
    ({'laser_upside_down': 'yes'}, 'true or false'),
    ({'icp.max_iterations': 2.5}, 'integer'),
    ({'icp.no_such_thing': 1}, 'unknown parameter icp.no_such_thing'),
    ({'matcher': 'ndt'}, 'valid names'),
])
def test_bad_values_are_refused_with_a_reason(values, words):
    with pytest.raises(ParameterError, match=words):
        pipeline_config_from_params(values)


def test_unknown_matcher_lists_valid_names():
    with pytest.raises(UnknownMatcherError) as err:
        create_matcher('ndt')
    for name in matcher_names():
        assert name in str(err.value)


ORDERED = {
    ('global_search_linear', 'global_search_max_linear'),
    ('diagnostics_warn_failure_rate', 'diagnostics_error_failure_rate'),
    ('diagnostics_warn_processing_time', 'diagnostics_error_processing_time'),
    ('icp.min_keep_fraction', 'icp.max_keep_fraction'),
    ('plicp.min_keep_fraction', 'plicp.max_keep_fraction'),
    ('nicp.normal_min_neighbours', 'nicp.normal_neighbours'),
    ('nicp.normal_min_neighbours', 'nicp.information_neighbours'),
    ('nicp.flat_curvature', 'nicp.max_curvature'),
    ('imls.min_neighbours', 'imls.max_neighbours'),
    ('imls.normal_min_neighbours', 'imls.normal_neighbours'),
}
"""The audit of every declared parameter (issue 39): each minimum and its maximum, each
threshold and the one it must stay below. Not ordered on purpose: nicp.capture_distance
(no capture stage when not above max_correspondence_distance), plicp's
coarse_correspondence_distance and map_huber_sigma (0 = off), imls's
information_neighbours (0 = the matching normals)."""


def test_every_ordered_pair_is_declared_and_its_defaults_hold_it():
    from laser_odom.core.configuration.node import ordered_pairs, parameter_specs
    assert set(ordered_pairs()) == ORDERED
    defaults = {spec.name: spec.default for spec in parameter_specs()}
    assert all(defaults[low] <= defaults[high] for low, high in ORDERED)


@pytest.mark.parametrize('low, high', sorted(ORDERED))
def test_a_crossed_pair_is_refused_in_one_line_naming_both(low, high):
    from laser_odom.core.configuration.node import check_values, parameter_specs
    spec = {s.name: s for s in parameter_specs()}[high]
    integer = isinstance(spec.default, int)
    high_value = type(spec.default)(max(spec.info.low, 2 if integer else 0.2))
    crossed = {high: high_value, low: high_value + (1 if integer else 0.1)}
    with pytest.raises(ParameterError) as error:
        check_values(crossed)
    message = str(error.value)
    assert message == (f'{low}={crossed[low]:g} must not exceed {high}={crossed[high]:g}')
    # Equal is allowed: a minimum at its maximum.
    assert check_values({**crossed, low: crossed[high]}).values[low] == crossed[high]
