"""Population traits: each wearer's own effect parameters (sim.scene.TraitSpec,
sim.population.wearer_traits), read from a scene file with one clear line per mistake."""
import copy
import math

import numpy as np
import pytest
import yaml

from fabric_guidance.paths import config_path
from fabric_guidance.sim.population import sample_wearer
from fabric_guidance.sim.scene import SceneError, scene_from_dict

BASE = yaml.safe_load(config_path('scenes/paper-fitted-speed.yaml').read_text())


def _scene(traits, subjects=15, seed=2025):
    data = copy.deepcopy(BASE)
    data['population']['traits'] = traits
    data['population']['subjects'] = subjects
    data['seed'] = seed
    return scene_from_dict(data, 'test.yaml')


PACE = {'sd': 0.4, 'scale': 'log', 'params': ['hololens_view.confirm_s', 'hololens_view.search_base_s']}
MISREAD = {'sd': 1.0, 'scale': 'logit', 'params': ['cue_misreading.direction_p']}


def test_a_trait_moves_its_parameters_together_around_the_scenes_value():
    scene = _scene({'pace': PACE}, subjects=400)
    confirm = scene.effect('hololens_view').params_dict['confirm_s']
    base = scene.effect('hololens_view').params_dict['search_base_s']
    u = []
    for i in range(400):
        w = sample_wearer(scene, i)
        p = w.effect_params['hololens_view']
        assert math.log(p['confirm_s'] / confirm) == pytest.approx(w.traits['pace'])
        assert math.log(p['search_base_s'] / base) == pytest.approx(w.traits['pace'])
        u.append(w.traits['pace'])
    assert np.std(u) == pytest.approx(0.4, rel=0.15)     # sd on the log scale
    assert abs(np.median(u)) < 0.1                        # the scene's value is the median


def test_a_wearer_keeps_their_traits_whatever_else_the_population_has():
    alone = _scene({'pace': PACE})
    both = _scene({'misreading': MISREAD, 'pace': PACE})
    for i in range(5):
        assert sample_wearer(alone, i).traits['pace'] == sample_wearer(both, i).traits['pace']
        assert sample_wearer(alone, i).suit_laws == sample_wearer(both, i).suit_laws
    other_seed = _scene({'misreading': MISREAD, 'pace': PACE}, seed=7)
    assert sample_wearer(both, 0).traits != sample_wearer(other_seed, 0).traits


def test_a_probability_stays_within_its_parameters_range():
    scene = _scene({'misreading': dict(MISREAD, sd=4.0)}, subjects=200)
    values = [sample_wearer(scene, i).effect_params['cue_misreading']['direction_p'] for i in range(200)]
    assert max(values) == 0.5 and min(values) > 0.0      # direction_p is at most 0.5


def test_without_traits_a_wearer_has_the_scenes_parameters():
    data = copy.deepcopy(BASE)
    data['population'].pop('traits', None)
    w = sample_wearer(scene_from_dict(data, 'test.yaml'), 3)
    assert w.traits == {} and w.effect_params == {}


@pytest.mark.parametrize('traits, message', [
    ({'x': {'sd': 1, 'scale': 'log', 'params': ['nosuch.p']}}, 'lists no effect'),
    ({'x': {'sd': 1, 'scale': 'log', 'params': ['hololens_view.nosuch']}}, 'not a number of hololens_view'),
    ({'x': {'sd': 1, 'scale': 'cubic', 'params': ['hololens_view.confirm_s']}}, 'scale'),
    ({'x': {'sd': -1, 'scale': 'log', 'params': ['hololens_view.confirm_s']}}, 'traits.x.sd'),
    ({'x': {'sd': 1, 'scale': 'logit', 'params': ['hololens_view.dummies']}}, 'logit scale'),
    ({'x': PACE, 'y': dict(PACE, scale='logit')}, 'already varied by trait'),
    ({'x': {'sd': 1, 'params': 'hololens_view.confirm_s'}}, 'must list effect.parameter'),
])
def test_a_bad_trait_is_one_line_naming_the_file_and_field(traits, message):
    with pytest.raises(SceneError, match=message) as info:
        _scene(traits)
    assert str(info.value).startswith('test.yaml: field "population.traits.')
    assert '\n' not in str(info.value)


def test_two_traits_on_one_parameter_add_on_its_scale():
    """A trait shared by several conditions (haptic_familiarity) and one of a single cue
    (misreading) both move direction_p: the wearer's value is the median moved by both draws."""
    import math
    shared = {'sd': 0.8, 'scale': 'logit', 'params': ['cue_misreading.direction_p']}
    scene = _scene({'misreading': MISREAD, 'familiarity': shared}, subjects=5)
    median = scene.effect('cue_misreading').params_dict['direction_p']
    for i in range(5):
        w = sample_wearer(scene, i)
        value = median
        for u in (w.traits['misreading'], w.traits['familiarity']):     # in the order listed, each clipped
            value = min(0.5, 1 / (1 + math.exp(-(math.log(value / (1 - value)) + u))))
        assert w.effect_params['cue_misreading']['direction_p'] == pytest.approx(value)
        assert w.traits['familiarity'] != 0.0
