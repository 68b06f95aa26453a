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
