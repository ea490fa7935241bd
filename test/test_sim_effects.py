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
    assert set(REGISTRY) == {'gaze_noise', 'datagram_loss', 'datagram_latency', 'regulator_lag', 'suit_hysteresis',
                             'weber_perception', 'reaction_delay', 'body_dynamics', 'speech_latency'}
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
    cmap = ChannelMap.load(config_path('channel_map.yaml'))
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
