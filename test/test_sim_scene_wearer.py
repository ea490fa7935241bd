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


def test_key_press_follows_the_headless_rules():
    """KeyPress: speed presses once the sent gaze has stayed within acceptance_deg for dwell_s,
    once per target; accuracy once the wearer has acted and held still for settle_s, or at
    timeout_s."""
    from types import SimpleNamespace

    from fabric_guidance.sim.scene import AccuracyProtocol, SpeedProtocol
    from fabric_guidance.sim.scene_wearer import KeyPress
    dt = 1 / 60
    key = KeyPress(SpeedProtocol(), dt)
    key.present(0.0, (20.0, 10.0))
    off = [key.sent(i * dt, 20.0 + 5.5, 10.0) for i in range(60)]          # 5.5 deg away: never
    assert not any(off)
    on = [key.sent(1.0 + i * dt, 21.0, 10.5) for i in range(60)]
    first = on.index(True)
    assert abs(first * dt - 0.3) < 1.5 * dt and on.count(True) == 1      # after the dwell, once
    acc = AccuracyProtocol()
    key = KeyPress(acc, dt)
    key.present(0.0, (30.0, 0.0))
    wearer = SimpleNamespace(torso_yaw=0.0, head_yaw=0.0, torso_pitch=0.0, head_pitch=0.0, acting=False)
    assert not any(key.stepped(i * dt, wearer) for i in range(1, 120))     # still, but not acted yet
    wearer.acting = True
    presses = [key.stepped(2.0 + i * dt, wearer) for i in range(120)]
    assert presses.count(True) == 1 and abs(presses.index(True) * dt - acc.settle_s) < 2 * dt
    key.present(10.0, (30.0, 0.0))
    wearer.acting = False
    presses = [key.stepped(10.0 + i * dt, wearer) for i in range(1, int(acc.timeout_s / dt) + 2)]
    assert presses.count(True) == 1 and True in presses[-2:]                # at the timeout


def test_key_press_is_repeated_while_a_refused_target_is_still_there():
    """A target still shown REPRESS_S after a press was refused by the session: the simulated
    participant presses again by the same rule; after withdraw() never."""
    from fabric_guidance.sim.scene import SpeedProtocol
    from fabric_guidance.sim.scene_wearer import REPRESS_S, KeyPress
    dt = 1 / 90
    key = KeyPress(SpeedProtocol(), dt)
    key.present(0.0, (10.0, 0.0))
    times = [i * dt for i in range(int(3.0 / dt))]
    presses = [t for t in times if key.sent(t, 10.5, 0.0)]
    assert len(presses) == 3
    assert all(b - a >= REPRESS_S for a, b in zip(presses, presses[1:]))
    key.withdraw()
    assert not any(key.sent(3.0 + i * dt, 10.5, 0.0) for i in range(300))
