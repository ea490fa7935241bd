"""Each effect of the scene simulator in isolation: it does what its docstring says, and its
randomness is its own."""
import math

import numpy as np
import pytest

from fabric_guidance.core.channels import ChannelMap
from fabric_guidance.paths import config_path
from fabric_guidance.sim import effects as fx
from fabric_guidance.sim.effects import (REGISTRY, EffectError, RunContext, effect_class, make_effect)

DT = 0.01


def started(name, dt=DT, wearer=0, run=(2, 1, 0), seed=7, **params):
    e = make_effect(name, params)
    e.start(RunContext(dt, seed, wearer, run))
    return e


# ---- registry and parameters ----------------------------------------------------------------

def test_registry_names_every_effect_of_the_design():
    assert set(REGISTRY) == {
        'gaze_noise', 'datagram_loss', 'datagram_latency', 'regulator_lag', 'suit_hysteresis',
        'weber_perception', 'reaction_delay', 'body_dynamics', 'speech_latency',
        'cue_misreading', 'surface_resistance', 'relative_perception', 'hololens_view'}
    for name, cls in REGISTRY.items():
        assert cls.name == name and cls.stage in fx.STAGES
        doc = cls.__doc__
        for param, (default, unit) in cls.parameters().items():
            assert param in doc, f'{name} does not document {param}'
        assert 'default' in doc and ('assumption' in doc or 'paper' in doc), f'{name}: say where defaults come from'


def test_unknown_effect_name_lists_the_valid_ones():
    with pytest.raises(EffectError) as err:
        effect_class('jitter')
    msg = str(err.value)
    assert "'jitter'" in msg and all(name in msg for name in REGISTRY)


def test_unknown_or_bad_parameters_name_the_field():
    with pytest.raises(EffectError, match=r'regulator_lag: unknown parameter\(s\) \[.tau.\].*tau_s'):
        make_effect('regulator_lag', {'tau': 0.1})
    with pytest.raises(EffectError, match=r'regulator_lag\.tau_s must be > 0'):
        make_effect('regulator_lag', {'tau_s': 0.0})
    with pytest.raises(EffectError, match=r'gaze_noise\.sd_deg must be a number'):
        make_effect('gaze_noise', {'sd_deg': 'big'})
    with pytest.raises(EffectError, match=r'datagram_loss\.burst_len must be >='):
        make_effect('datagram_loss', {'probability': 0.5, 'burst_len': 1.5})


# ---- pressure side ----------------------------------------------------------------------------

def test_regulator_lag_reaches_63_percent_after_tau():
    lag = started('regulator_lag', tau_s=0.15)
    cmd = [100.0, 0.0, 200.0, 0.0]
    for _ in range(15):                      # 0.15 s at dt = 0.01
        out = lag.pressure(cmd)
    assert out[0] == pytest.approx(100.0 * (1 - math.exp(-1)), abs=1e-9)
    assert out[2] == pytest.approx(200.0 * (1 - math.exp(-1)), abs=1e-9)
    assert out[1] == 0.0
    for _ in range(300):
        out = lag.pressure(cmd)
    assert out[0] == pytest.approx(100.0, abs=1e-6)


def test_regulator_lag_is_exact_whatever_the_step():
    for dt in (0.001, 0.0125, 0.05):
        lag = started('regulator_lag', dt=dt, tau_s=0.2)
        n = int(round(0.4 / dt))
        for _ in range(n):
            out = lag.pressure([50.0, 0, 0, 0])
        assert out[0] == pytest.approx(50.0 * (1 - math.exp(-2)), rel=1e-9)


def test_suit_hysteresis_holds_within_the_band_and_follows_beyond():
    hyst = started('suit_hysteresis', band_kpa=20.0)
    out = hyst.pressure([100.0, 0, 0, 0])
    assert out[0] == 90.0                     # rising: band/2 behind
    for p in (95.0, 100.0, 82.0, 99.0, 80.0):  # within +-10 of 90: no change
        assert hyst.pressure([p, 0, 0, 0])[0] == 90.0
    assert hyst.pressure([120.0, 0, 0, 0])[0] == 110.0
    assert hyst.pressure([50.0, 0, 0, 0])[0] == 60.0      # falling: band/2 ahead
    assert hyst.pressure([0.0, 0, 0, 0])[0] == 10.0       # play left at vent
    assert hyst.pressure([0.0, 0, 0, 0])[1] == 0.0        # never below 0


def test_pressure_effects_per_direction_equal_the_mean_of_18_simulated_channels():
    """The engine simulates channel effects once per direction; per channel gives the same."""
    cmap = ChannelMap.load(config_path('hardware/channel_map.yaml'))
    rng = np.random.default_rng(3)
    for layout in ('suit', 'arm'):
        lag, hyst = started('regulator_lag', tau_s=0.15), started('suit_hysteresis', band_kpa=20.0)
        alpha = 1 - math.exp(-DT / 0.15)
        reg = np.zeros(len(cmap.channels))
        suit = np.zeros(len(cmap.channels))
        cmd = np.zeros(4)
        for i in range(400):
            if i % 3 == 0:
                cmd = np.where(rng.random(4) < 0.5, rng.uniform(0, 375, 4), cmd)
            ch = cmap.to_channels(cmd, layout)
            reg += (ch - reg) * alpha
            suit = np.maximum(np.clip(suit, reg - 10.0, reg + 10.0), 0.0)
            felt_channels = cmap.to_directions(suit, layout)
            per_direction = hyst.pressure(lag.pressure(cmap.to_directions(ch, layout).tolist()))
            np.testing.assert_allclose(per_direction, felt_channels, rtol=1e-12, atol=1e-9)


# ---- perception ---------------------------------------------------------------------------------

def test_weber_percept_ignores_a_5_percent_change_and_follows_a_20_percent_one():
    weber = started('weber_perception', fraction=0.1)
    assert weber.percept([100.0, 0, 0, 0])[0] == 100.0     # from nothing, anything is felt
    assert weber.percept([105.0, 0, 0, 0])[0] == 100.0
    assert weber.percept([95.0, 0, 0, 0])[0] == 100.0
    assert weber.percept([120.0, 0, 0, 0])[0] == 120.0
    assert weber.percept([110.0, 0, 0, 0])[0] == 120.0     # -8.3 % of the percept: not felt
    assert weber.percept([100.0, 0, 0, 0])[0] == 100.0     # -16.7 %: felt
    assert weber.percept([0.0, 0, 0, 0])[0] == 0.0


def test_weber_percept_is_relative_to_the_current_percept():
    weber = started('weber_perception', fraction=0.1)
    weber.percept([100.0, 0, 0, 0])
    for p in np.arange(100.0, 110.0, 0.5):                # a slow creep of 9.5 % is not felt
        assert weber.percept([float(p), 0, 0, 0])[0] == 100.0
    assert weber.percept([110.5, 0, 0, 0])[0] == 110.5


def test_reaction_delay_shifts_by_whole_steps_and_is_per_wearer():
    d = started('reaction_delay', mean_s=0.25, sd_s=0.0)
    assert d.steps == 25
    d.reset(0)
    out = [d.delay(i) for i in range(1, 60)]
    assert out[:25] == [0] * 25 and out[25:] == list(range(1, 60 - 25))
    # Each wearer has their own delay, the same in every run.
    a = [started('reaction_delay', wearer=w, run=(2, c, r)).delay_s for w in range(3) for c, r in ((1, 0), (4, 5))]
    assert a[0] == a[1] and a[2] == a[3] and a[4] == a[5]
    assert len({a[0], a[2], a[4]}) == 3


def test_reaction_delay_of_zero_passes_through():
    d = started('reaction_delay', mean_s=0.0, sd_s=0.0)
    d.reset(None)
    assert d.delay('x') == 'x'


# ---- gaze stream ---------------------------------------------------------------------------------

def test_gaze_noise_has_the_stated_sd_and_leaves_the_sample_otherwise():
    noise = started('gaze_noise', sd_deg=2.0)
    out = np.array([noise.gaze(0.0, (i, 0.1 * i, 10.0, -5.0)) for i in range(4000)])
    assert np.all(out[:, 0] == np.arange(4000))
    assert np.std(out[:, 2]) == pytest.approx(2.0, rel=0.05)
    assert np.mean(out[:, 3]) == pytest.approx(-5.0, abs=0.1)
    assert started('gaze_noise', sd_deg=0.0).gaze(0.0, (1, 0.0, 3.0, 4.0)) == (1, 0.0, 3.0, 4.0)


def test_draws_in_blocks_equal_draws_one_by_one():
    d = fx.Draws(fx.generator(1, 'x', 0), 'normal')
    blocks = [d.next() for _ in range(1500)]
    one_by_one = [float(fx.generator(1, 'x', 0).standard_normal(1500)[i]) for i in (0, 511, 512, 1499)]
    assert [blocks[i] for i in (0, 511, 512, 1499)] == one_by_one


def test_datagram_loss_rate_and_bursts():
    loss = started('datagram_loss', probability=0.1)
    lost = np.array([loss.gaze(0.0, (i, 0.0, 0.0, 0.0)) is None for i in range(40000)])
    assert lost.mean() == pytest.approx(0.1, abs=0.01)
    bursty = started('datagram_loss', probability=0.1, burst_len=5.0)
    lost = np.array([bursty.gaze(0.0, (i, 0.0, 0.0, 0.0)) is None for i in range(100000)])
    assert lost.mean() == pytest.approx(0.1, abs=0.02)
    edges = np.flatnonzero(np.diff(lost.astype(int)) == -1).size   # ends of loss runs
    assert lost.sum() / edges == pytest.approx(5.0, rel=0.15)
    assert started('datagram_loss', probability=0.0).gaze(0.0, (1, 0.0, 0.0, 0.0)) == (1, 0.0, 0.0, 0.0)


def test_datagram_latency_delays_and_drops_overtaken_samples():
    lat = started('datagram_latency', mean_s=0.05, jitter_s=0.0)
    arrivals = {}
    for i in range(100):
        t = i * DT
        s = lat.gaze(t, (i, t, float(i), 0.0))
        if s is not None:
            arrivals[s[0]] = t
    assert all(arrivals[i] == pytest.approx(i * DT + 0.05) for i in range(90))
    jittered = started('datagram_latency', mean_s=0.05, jitter_s=0.03)
    seqs = []
    for i in range(3000):
        s = jittered.gaze(i * DT, (i, i * DT, 0.0, 0.0))
        if s is not None:
            seqs.append(s[0])
    assert seqs == sorted(seqs) and len(seqs) < 3000          # never older than the last delivered


def test_datagram_latency_draws_are_lognormal_with_the_stated_mean_and_sd():
    lat = started('datagram_latency', mean_s=0.05, jitter_s=0.02)
    z = np.array([lat._draws.next() for _ in range(20000)])
    delays = np.exp(lat.mu + lat.sigma * z)
    assert delays.mean() == pytest.approx(0.05, rel=0.03) and delays.std() == pytest.approx(0.02, rel=0.05)


def test_speech_latency_is_synthesis_plus_speaking_time():
    sp = started('speech_latency', mean_s=0.4, sd_s=0.0, per_word_s=0.35)
    assert sp.latency('36 to the right and 12 upward') == pytest.approx(0.4 + 7 * 0.35)
    assert sp.latency('straight ahead') == pytest.approx(0.4 + 2 * 0.35)


def test_each_effect_has_its_own_stream_keyed_by_name_wearer_and_run():
    def first(name, wearer=0, run=(2, 1, 0), seed=7):
        return fx.generator(seed, name, wearer, run).standard_normal(3).tolist()
    base = first('gaze_noise')
    assert first('gaze_noise') == base
    assert first('datagram_latency') != base
    assert first('gaze_noise', wearer=1) != base
    assert first('gaze_noise', run=(2, 2, 0)) != base
    assert first('gaze_noise', seed=8) != base


# ---- the wearer who can be wrong ----------------------------------------------------------------

def test_new_effect_parameters_out_of_range_name_the_field():
    with pytest.raises(EffectError,
                       match=r'^cue_misreading\.direction_p must be <= 0\.5 -, got 0\.7$'):
        make_effect('cue_misreading', {'direction_p': 0.7})
    with pytest.raises(EffectError,
                       match=r'^surface_resistance\.threshold_kpa_deg must be > 0 kPa deg'):
        make_effect('surface_resistance', {'threshold_kpa_deg': 0.0})
    with pytest.raises(EffectError, match=r'^relative_perception\.fraction must be > 0'):
        make_effect('relative_perception', {'fraction': 0.0})
    with pytest.raises(EffectError, match=r'^hololens_view\.dummies must be a whole number'):
        make_effect('hololens_view', {'dummies': 2.5})
    with pytest.raises(EffectError, match=r'^hololens_view\.confirm_s must be >= 0 s'):
        make_effect('hololens_view', {'confirm_s': -1.0})


def test_cue_misreading_flips_directions_at_the_stated_rate_with_a_fixed_number_of_draws():
    cue = started('cue_misreading', direction_p=0.3, magnitude_sd=0.2)
    flips, logs = [], []
    for _ in range(4000):
        cue.read()
        flips += [cue.factor_h < 0, cue.factor_v < 0]
        logs.append(math.log(abs(cue.factor_h)))
    assert np.mean(flips) == pytest.approx(0.3, abs=0.02)
    assert np.std(logs) == pytest.approx(0.2, rel=0.05)
    assert np.mean(logs) == pytest.approx(0.0, abs=0.01)
    # A correct read (the wearer felt the resistance) has the right directions, and consumes the
    # same draws: the next reads are the same as if it had been an ordinary read.
    a, b = started('cue_misreading', direction_p=0.5), started('cue_misreading', direction_p=0.5)
    a.read(correct_direction=True)
    b.read()
    assert a.sign_h == a.sign_v == 1.0
    for _ in range(20):
        a.read(), b.read()
        assert (a.factor_h, a.factor_v) == (b.factor_h, b.factor_v)


def test_cue_misreadings_trial_sds_move_each_runs_rates_and_arm_read_time_and_nothing_else():
    """trial_sd: a run's rates are the median's moved by trial_sd * z (logit), z ~ N(0, 1) from a
    stream of its own: over many runs the logits have that spread around the median's, both rates
    move together, a rate of 0 stays 0, none exceeds 0.5, and the reads' draws are untouched."""
    def logit(p):
        return math.log(p / (1 - p))

    runs = [started('cue_misreading', run=(2, 1, r), direction_p=0.2, arm_direction_p=0.05, trial_sd=0.8)
            for r in range(3000)]
    arm = np.array([logit(c.arm_direction_p) for c in runs])      # 0.05: never near 0.5 here
    assert np.median(arm) == pytest.approx(logit(0.05), abs=0.06)
    assert np.std(arm) == pytest.approx(0.8, rel=0.06)
    unclipped = [i for i, c in enumerate(runs) if c.direction_p < 0.5]
    assert 0.9 * len(runs) < len(unclipped) < len(runs)
    np.testing.assert_allclose([logit(runs[i].direction_p) - arm[i] for i in unclipped],
                               logit(0.2) - logit(0.05))                # one shift for both
    assert max(c.direction_p for c in runs) == 0.5 and all(c.p == c.direction_p for c in runs)
    assert {started('cue_misreading', run=(2, 1, r), direction_p=0.0, trial_sd=2.0).direction_p
            for r in range(50)} == {0.0}
    # arm_read_trial_sd: the arm's read time of a run is arm_read_s times exp(sd * z - sd^2 / 2),
    # so arm_read_s stays the mean.
    arm_runs = [started('cue_misreading', run=(2, 3, r), arm_read_s=2.0, arm_read_trial_sd=0.5)
                for r in range(3000)]
    times = np.array([c.arm_read_s for c in arm_runs])
    assert np.std(np.log(times)) == pytest.approx(0.5, rel=0.06)
    assert np.mean(times) == pytest.approx(2.0, rel=0.03)
    assert np.median(np.log(times / 2.0)) == pytest.approx(-0.125, abs=0.04)
    assert {c.direction_p for c in arm_runs} == {0.15}        # the rates stay the scene's
    # The reads draw from their own streams: the signs of a run's reads are those of a run
    # without trial_sd at the same rate.
    moved = runs[7]
    plain = started('cue_misreading', run=(2, 1, 7), direction_p=moved.direction_p)
    for _ in range(50):
        moved.read(), plain.read()
        assert (moved.factor_h, moved.factor_v) == (plain.factor_h, plain.factor_v)


def test_cue_misreading_of_zero_reads_exactly():
    cue = started('cue_misreading', direction_p=0.0, magnitude_sd=0.0)
    for _ in range(100):
        cue.read()
        assert (cue.factor_h, cue.factor_v) == (1.0, 1.0)


def _resistance_steps(exerted_of_step, v_yaw=-30.0, threshold=1500.0):
    """Steps until surface_resistance fires for a wearer turning right at v_yaw deg/s while
    the suit pulls left with exerted_of_step(i) kPa."""
    r = started('surface_resistance', threshold_kpa_deg=threshold)
    for i in range(100000):
        if r.accumulate([exerted_of_step(i), 0.0, 0.0, 0.0], v_yaw, 0.0, DT):
            return i + 1
    return None


def test_surface_resistance_fires_sooner_with_rising_pressure_and_faster_wrong_moves():
    constant = _resistance_steps(lambda i: 100.0)
    rising = _resistance_steps(lambda i: 100.0 + 2.0 * i)        # Eq. 5 adding pressure
    assert constant == math.ceil(1500.0 / (100.0 * 30.0 * DT))   # J = p * speed * t
    assert rising < constant
    assert _resistance_steps(lambda i: 100.0, v_yaw=-60.0) < constant
    # Moving the way the suit pulls builds nothing.
    assert _resistance_steps(lambda i: 100.0, v_yaw=+30.0) is None


def test_surface_resistance_counts_the_net_pull_not_a_residual_on_the_other_side():
    r = started('surface_resistance', threshold_kpa_deg=10.0)
    # Turning left under a strong right pull and a 10 kPa left residual: resisted by 190 kPa.
    for _ in range(10):
        r.accumulate([10.0, 200.0, 0.0, 0.0], 30.0, 0.0, DT)
    assert r.fired >= 1
    r = started('surface_resistance', threshold_kpa_deg=10.0)
    for _ in range(1000):                          # turning right with it: never
        r.accumulate([10.0, 200.0, 0.0, 0.0], -30.0, 0.0, DT)
    assert r.fired == 0 and r.impulse == 0.0


def test_relative_perception_notices_a_rise_not_a_level_nor_the_onset():
    rel = started('relative_perception', fraction=0.14, settle_s=0.2)
    # The onset: the pressure rises from 0 within the first settle_s: no notice.
    for i in range(20):
        assert not rel.rise([200.0 * (i + 1) / 20, 0, 0, 0])
    for _ in range(300):                            # a steady level: no notice
        assert not rel.rise([200.0, 0, 0, 0])
    assert not rel.rise([220.0, 0, 0, 0])          # +10 %: below the fraction
    assert rel.rise([230.0, 0, 0, 0])              # +15 %: noticed
    assert rel.noticed == 1


def test_relative_perception_differs_from_weber_perception():
    """weber_perception is a dead band on the percept: a +10 % change is not felt at all.
    relative_perception leaves the percept alone and notices rises above its fraction."""
    weber = started('weber_perception', fraction=0.14)
    weber.percept([200.0, 0, 0, 0])
    assert weber.percept([220.0, 0, 0, 0])[0] == 200.0
    assert not hasattr(make_effect('relative_perception'), 'percept')


def _view(**params):
    v = started('hololens_view', **params)
    v.present((30.0, 0.0), (60.0, 30.0))
    return v


def test_hololens_view_sees_only_on_the_display_and_in_the_central_field():
    v = _view(search_base_s=0.0, search_per_item_s=0.0)
    # 30 deg to the side: within the 30 deg central field, outside the 43 deg wide display.
    assert not v.update(0.0, 0.0, 0.0, True)
    assert not v.update(0.0, 10.0, 0.0, False)     # on the display, outside the central field
    assert v.update(0.0, 10.0, 0.0, True)          # 20 deg: both
    # Stopped, the wearer scans with the head: 15 deg more on each side.
    v = _view(search_base_s=0.0, search_per_item_s=0.0)
    assert v.update(0.0, 0.0, 0.0, False, still=True)


def test_hololens_view_search_time_grows_with_the_dummies_in_view_and_the_key_waits_for_confirm():
    v = _view(search_base_s=0.4, search_per_item_s=0.025, confirm_s=0.5)
    t = 0.0
    while not v.update(t, 20.0, 0.0, True):
        t += DT
    n, need = v.searches[0]
    assert n == sum(1 for d in v.dummy_pos if v.in_display(20.0, 0.0, *d))
    assert need == pytest.approx(0.4 + 0.025 * n)
    assert t == pytest.approx(need, abs=DT)
    assert v.key_ready_t == pytest.approx(t + 0.5)
    # Leaving the view restarts the search.
    v = _view(search_base_s=0.4, search_per_item_s=0.0)
    v.update(0.0, 20.0, 0.0, True)
    v.update(0.3, 20.0, 0.0, True)
    assert not v.update(0.35, -40.0, 0.0, True)
    assert not v.update(0.5, 20.0, 0.0, True) and not v.update(0.85, 20.0, 0.0, True)
    assert v.update(0.9, 20.0, 0.0, True)
    assert math.isinf(started('hololens_view').key_ready_t)


def test_hololens_view_dummies_are_the_papers_fifty_in_the_region_per_target():
    v = _view()
    assert len(v.dummy_pos) == 50
    assert all(abs(y) <= 60.0 and abs(p) <= 30.0 for y, p in v.dummy_pos)
    first = list(v.dummy_pos)
    v.present((0.0, 10.0))
    assert v.dummy_pos != first and _view().dummy_pos == first      # seeded, new per target


def test_a_scene_with_a_new_effect_out_of_range_is_one_scene_error_naming_the_field():
    from fabric_guidance.sim.scene import SceneError, load_scene, scene_from_dict
    base = load_scene('paper-fitted-speed')
    data = {'name': 'x', 'seed': 1, 'protocol': {'kind': 'speed'},
            'population': {'laws': {d: {'a': 20.0, 'b': 0.6, 'c': 20.0}
                                    for d in ('left', 'right', 'down', 'up')}},
            'effects': [{'hololens_view': {'scan_deg': 120.0}}]}
    with pytest.raises(SceneError) as err:
        scene_from_dict(data, 'scene.yaml')
    msg = str(err.value)
    assert '\n' not in msg
    assert msg.startswith('scene.yaml: field "effects[0].hololens_view" '
                          'hololens_view.scan_deg must be <= 90')
    assert base.effect('cue_misreading') is not None
