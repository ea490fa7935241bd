"""The wearer side of a scene as the ROS graph runs it (sim/scene_wearer.py SceneSide), without
ROS: which effects it applies, its seeding, and its refusal of a wearer the scene lacks."""
import pytest

from fabric_guidance.sim.scene_wearer import REALISED_ELSEWHERE, SceneSide, load_scene_file

DT = 1 / 60
PAPER_SPEED_HERE = ['suit_hysteresis', 'weber_perception', 'reaction_delay', 'body_dynamics',
                    'gaze_noise', 'datagram_loss', 'datagram_latency']


def run(side, steps=120, pressures=(60.0, 0.0, 0.0, 0.0), target=(25.0, 5.0)):
    return [side.step(pressures, True, target) for _ in range(steps)]


def test_the_side_applies_the_wearer_effects_and_leaves_regulator_lag_to_the_plc():
    scene = load_scene_file('paper-speed')
    side = SceneSide(scene, 0, 1, DT)
    assert side.applied_effects() == PAPER_SPEED_HERE
    assert 'regulator_lag' in scene.effect_names and 'regulator_lag' in REALISED_ELSEWHERE
    assert 'speech_latency' not in SceneSide(scene, 0, 1, DT).applied_effects()   # condition 1


def test_the_same_scene_and_wearer_give_the_same_samples():
    scene = load_scene_file('paper-speed')
    a, b = run(SceneSide(scene, 2, 1, DT)), run(SceneSide(scene, 2, 1, DT))
    assert a == b
    assert any(s is not None for s in a)
    assert run(SceneSide(scene, 3, 1, DT)) != a     # another wearer, other draws


def test_a_wearer_the_scene_lacks_is_one_line_naming_the_parameter():
    scene = load_scene_file('ideal')
    with pytest.raises(ValueError,
                       match=r'^parameter wearer_index: the scene ideal has wearers 0\.\.'):
        SceneSide(scene, scene.population.subjects, 1, DT)


def test_hololens_view_is_reported_as_headless_only_not_as_realised_by_wearer_sim():
    from fabric_guidance.core import condition
    from fabric_guidance.sim.scene_plan import effects_where
    scene = load_scene_file('paper-fitted-speed')
    assert 'hololens_view' in scene.effect_names
    assert 'hololens_view' not in SceneSide(scene, 0, 1, DT).applied_effects()
    where = effects_where(scene, condition(1), 0.15)
    assert 'hololens_view' not in where['wearer_sim']
    assert where['headless only (not realised in the graph)'] == ['hololens_view']
    assert where['mock_plc'] == ['regulator_lag (regulator_tau_s 0.15 s)']


def test_the_wearer_sees_a_visible_target_in_the_central_field_as_in_the_engine():
    # Senses.seen stops the cue effects' 'still' re-reads while the target is in view; the
    # engine sets it from visual capture, and so must the graph's wearer.
    scene = load_scene_file('paper-fitted-speed')
    side = SceneSide(scene, 0, 1, DT)
    assert side.senses._cue_on
    side.step((0.0, 0.0, 0.0, 0.0), True, (5.0, 2.0))      # near the gaze: in the central field
    assert side.senses.seen
    side.step((0.0, 0.0, 0.0, 0.0), True, (-170.0, 0.0))   # behind the wearer
    assert not side.senses.seen
    side.step((0.0, 0.0, 0.0, 0.0), True, None)            # no target position yet
    assert not side.senses.seen


def test_in_condition_4_the_cue_effects_are_unused_in_the_report_and_on_the_side():
    """The haptic cue effects (stage 'cue') do nothing when speech guides: the side and the demo's
    report must say so, from one rule."""
    from fabric_guidance.core import condition
    from fabric_guidance.sim.scene_plan import effects_where
    scene = load_scene_file('paper-fitted-speed')
    cue = ['cue_misreading', 'surface_resistance', 'relative_perception']
    applied = SceneSide(scene, 0, 4, DT).applied_effects()
    assert not set(cue) & set(applied) and 'speech_latency' in applied
    where = effects_where(scene, condition(4), 0.15)
    assert set(cue) <= set(where['unused in condition 4'])
    assert set(cue) <= set(effects_where(scene, condition(1), 0.15)['wearer_sim'])
