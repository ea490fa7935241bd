"""`fabric-guidance sensitivity`: which parameters it sweeps (only assumed ones of listed
effects), how it sets them, that a known cause moves a headline the known way, its files, and
bad options."""
from __future__ import annotations

import contextlib
import io
import math
from pathlib import Path

from matplotlib import image
import pandas as pd
import pytest
import yaml

from fabric_guidance.experiments import sensitivity as S
from fabric_guidance.experiments import sensitivity_runs as R
from fabric_guidance.paths import config_path
from fabric_guidance.sim.effects import REGISTRY

PNG_SIGNATURE = b'\x89PNG\r\n\x1a\n'


def _scenes():
    return S.load_scenes(S.quick_settings())


def _keys(params):
    return [p.key for p in params]


def _without(scene, effect):
    return scene.with_effects([{e.name: e.params_dict} for e in scene.effects if e.name != effect])


def _scene_file(tmp_path: Path, name: str, drop: str) -> Path:
    """A copy of a shipped scene without one effect."""
    data = yaml.safe_load(Path(config_path(f'scenes/{name}.yaml')).read_text())
    data['effects'] = [e for e in data['effects']
                       if (e if isinstance(e, str) else next(iter(e))) != drop]
    data['name'] = f'{name}-reduced'
    path = tmp_path / f'{data["name"]}.yaml'
    path.write_text(yaml.safe_dump(data))
    return path


def _main(argv):
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = S.main(argv)
    return code, out.getvalue(), err.getvalue()


# ------------------------------------------------------------------------ which parameters

def test_every_parameter_of_every_listed_effect_and_the_population_and_dwell():
    spd, acc = _scenes()
    keys = _keys(S.assumed_parameters(spd, acc))
    expect = [f'{e}.{p}' for e in spd.effect_names for p, (default,
                                                           _) in REGISTRY[e].parameters().items()
              if (spd.effect(e).params_dict.get(p, default)) is not None
              and (e, p) not in R.MEASURED]
    assert 'speech_latency.per_word_s' not in keys     # fitted by fit-wearer: not an assumption
    assert 'population.arm_spread' not in keys         # profiled by fit-wearer: not an assumption
    assert [k for k in keys if not k.startswith(('population.', 'protocol.'))] == expect
    assert keys[-4:] == ['population.spread.a', 'population.spread.b', 'population.spread.c',
                         'protocol.dwell_s']
    assert 'datagram_loss.burst_len' not in keys       # unset optional: nothing to vary
    assert len(set(keys)) == len(keys)


def test_an_effect_no_scene_lists_is_not_swept_and_one_scene_is_enough():
    spd, acc = _scenes()
    keys = _keys(S.assumed_parameters(_without(spd, 'speech_latency'), _without(acc,
                                                                                'speech_latency')))
    assert not [k for k in keys if k.startswith('speech_latency.')]
    # listed by the accuracy scene only: swept, and applied there only
    params = S.assumed_parameters(_without(spd, 'speech_latency'), acc)
    p = next(p for p in params if p.key == 'speech_latency.mean_s')
    assert p.scenes == ('accuracy',)


def test_measured_or_fitted_parameters_are_not_swept(monkeypatch):
    spd, acc = _scenes()
    monkeypatch.setattr(R, 'MEASURED', {('gaze_noise', 'sd_deg')})
    keys = _keys(S.assumed_parameters(spd, acc, exclude=('protocol.dwell_s',)))
    assert 'gaze_noise.sd_deg' not in keys and 'protocol.dwell_s' not in keys
    assert 'reaction_delay.mean_s' in keys
    # a scene that lists its fitted parameters (an attribute the scene format may offer)
    object.__setattr__(spd, 'fitted', ('reaction_delay.mean_s',))
    assert 'reaction_delay.mean_s' not in _keys(S.assumed_parameters(spd, acc))


def test_low_and_high_values_zero_and_clipping():
    p = S.Parameter('datagram_loss.probability', '-', 0.6, 0.0, 1.0)
    assert p.values(0.5, 2.0) == (pytest.approx(0.3), 1.0)          # clipped to the range
    zero = S.Parameter('population.arm_spread', '(log) -', 0.0, 0.0, 3.0)
    low, high = zero.values(0.5, 2.0)
    assert low is None and high == R.SMALL_BY_UNIT['(log) -']          # 0 -> a small positive
    eff = S.Parameter('suit_hysteresis.band_kpa', 'kPa', 0.0, 0.0, None, default=20.0)
    assert eff.values(0.5, 2.0) == (None, 20.0)                        # the effect's own default
    top = S.Parameter('weber_perception.fraction', '-', 10.0, 0.0, 10.0)
    assert top.values(0.5, 2.0) == (5.0, None)                         # at the limit: no high side


def test_apply_sets_one_parameter_in_the_scenes_it_belongs_to():
    spd, acc = _scenes()
    params = {p.key: p for p in S.assumed_parameters(spd, acc)}
    s2 = S.apply(spd, 'speed', params['reaction_delay.mean_s'], 0.5)
    assert s2.effect('reaction_delay').params_dict['mean_s'] == 0.5
    sd = spd.effect('reaction_delay').params_dict['sd_s']
    assert s2.effect('reaction_delay').params_dict['sd_s'] == sd
    assert [e for e in s2.effects if e.name != 'reaction_delay'] == \
        [e for e in spd.effects if e.name != 'reaction_delay']
    dwell = params['protocol.dwell_s']
    assert S.apply(spd, 'speed', dwell, 0.6).protocol.dwell_s == 0.6
    assert S.apply(acc, 'accuracy', dwell, 0.6) == acc                  # no dwell in that protocol
    b = S.apply(acc, 'accuracy', params['population.spread.b'], 0.2).population.spread
    assert b == (acc.population.spread[0], 0.2, acc.population.spread[2])


# ------------------------------------------------------------------- a known cause, known way

def test_a_longer_reaction_delay_costs_targets_and_accuracy():
    """Acting on the percept later: fewer targets in 40 s and a larger key-press error (paired,
    same wearers and targets); a shorter one does not cost targets."""
    # The untuned scenes: there the delay's cost is not masked by the fitted wearer's re-reads,
    # which in a 2-wearer quick run can outweigh it.
    result = S.run_sensitivity(S.quick_settings(parameters=('reaction_delay.mean_s',), seeds=1,
                                                workers=1, speed_scene='paper-speed',
                                                accuracy_scene='paper-accuracy'))
    base = result.baseline
    runs = {r.side: r for r in result.runs}
    assert runs['high'].value == pytest.approx(2 * 0.25)
    assert runs['low'].value == pytest.approx(0.125)
    high, low = runs['high'].figures, runs['low'].figures
    assert high['c1_targets'] < base['c1_targets'] and high['c4_targets'] < base['c4_targets']
    assert high['c1_error_deg'] > base['c1_error_deg']
    assert low['c1_targets'] >= base['c1_targets'] and low['c4_targets'] >= base['c4_targets']
    # one baseline seed: no interval over seeds, so no move is called beyond noise, and the
    # table says so
    assert math.isnan(result.noise_sds()) and not result.beyond(runs['high'])
    assert all(math.isnan(lo) for _, lo, _, _ in result.seed_interval().values())
    table = S.markdown_table(result)
    assert 'one seed: no interval' in table and '**beyond noise**' not in table


# ------------------------------------------------------------------------------- the files

@pytest.fixture(scope='module')
def quick_run(tmp_path_factory):
    """A --quick run on scenes without speech_latency (through the command line)."""
    tmp = tmp_path_factory.mktemp('sensitivity')
    spd = _scene_file(tmp, 'paper-speed', 'speech_latency')
    acc = _scene_file(tmp, 'paper-accuracy', 'speech_latency')
    out = tmp / 'out'
    code, stdout, stderr = _main(['--quick', '--out', str(out), '--speed-scene', str(spd),
                                  '--accuracy-scene', str(acc), '--workers', '2'])
    return out, code, stdout, stderr


def test_quick_run_writes_table_report_and_tornado(quick_run):
    out, code, stdout, stderr = quick_run
    assert code == 0, stderr
    frame = pd.read_csv(out / 'sensitivity.csv')
    swept = set(frame['parameter']) - {'baseline'}
    assert not [k for k in swept if k.startswith('speech_latency')]    # cannot matter: absent
    assert {'reaction_delay.mean_s', 'population.spread.a', 'protocol.dwell_s'} <= swept
    assert (frame['side'] == 'baseline').sum() == S.quick_settings().seeds
    runs = frame[frame['seed'].notna()]
    for h in S.HEADLINES:
        assert runs[h].notna().all()
        moved = runs[runs['side'] != 'baseline']
        assert (moved[f'd_{h}'] == moved[h] - frame[frame['side'] == 'baseline'][h].iloc[0]).all()
    md = (out / 'sensitivity.md').read_text()
    # no row of a speech_latency parameter (the fitted one may be named among the skipped)
    assert not [ln for ln in md.splitlines() if ln.startswith('|') and 'speech_latency' in ln]
    assert '| baseline |' in md
    assert '![sensitivity](sensitivity.png)' in md
    # sorted by the largest move in seed SDs
    zs = [float(line.rsplit('|', 2)[1].split()[0]) for line in md.splitlines()
          if line.startswith('| ') and '(c' in line.rsplit('|', 2)[1]]
    assert zs == sorted(zs, reverse=True) and len(zs) == len(swept)
    png = out / 'sensitivity.png'
    assert png.read_bytes()[:8] == PNG_SIGNATURE
    assert image.imread(png).std() > 0.05
    lines = [ln for ln in stderr.splitlines() if ln.startswith('[')]
    assert len(lines) == len(runs)                                      # one progress line per run
    assert '| parameter |' in stdout


def test_the_baseline_interval_over_seeds_is_explicit_and_moves_are_judged_against_it(quick_run):
    """The table's baseline row gives the mean over the seeds with its 95 % t interval and the
    seed count; the CSV has them as rows; a move is beyond noise exactly when it exceeds one
    seed's 95 % prediction interval, t(0.975, k-1) x sqrt(1 + 1/k) seed SDs."""
    from scipy import stats as ss
    out = quick_run[0]
    frame = pd.read_csv(out / 'sensitivity.csv')
    k = S.quick_settings().seeds
    base = frame[frame['side'] == 'baseline']
    mean, lo, hi = (frame[frame['side'] == side].iloc[0] for side in ('seeds_mean', 'seeds_lo', 'seeds_hi'))
    factor = ss.t.ppf(0.975, k - 1) * math.sqrt(1 + 1 / k)
    for h in S.HEADLINES:
        assert mean[h] == pytest.approx(base[h].mean())
        sd = base[h].std(ddof=1)
        half = ss.t.ppf(0.975, k - 1) * sd / math.sqrt(k)
        assert (lo[h], hi[h]) == pytest.approx((mean[h] - half, mean[h] + half))
        assert lo[h] <= mean[h] <= hi[h]
    assert (frame['seeds'] == k).all()
    md = (out / 'sensitivity.md').read_text()
    row = next(ln for ln in md.splitlines() if ln.startswith('| baseline |'))
    assert f'{k} seed(s)' in row and row.count(f'mean over {k} seeds') == len(S.HEADLINES)
    assert f't(0.975, {k - 1}) x sqrt(1 + 1/{k}) = {factor:.2f} seed SDs' in md
    # the runs marked beyond noise are those whose move exceeds that many seed SDs (or the
    # figure's resolution, when the seeds happen to agree)
    moved = frame[frame['side'].isin(['low', 'high'])]
    resolution = {h: 0.01 if h.endswith('_deg') else 40.0 / 20.0 / 2 for h in S.HEADLINES}
    for _, r in moved.iterrows():
        expect = [h for h in S.HEADLINES
                  if abs(r[f'd_{h}']) > factor * max(base[h].std(ddof=1), resolution[h])]
        got = r['beyond_noise'].split(',') if isinstance(r['beyond_noise'], str) else []
        assert got == expect, r['parameter']


def test_central_field_moves_the_speed_figures_beyond_noise(quick_run):
    """Visual capture ends most searches in the paper scenes: halving the capture field costs
    condition 1 targets, far beyond the seed spread (a sign the figures rest on it)."""
    frame = pd.read_csv(quick_run[0] / 'sensitivity.csv')
    field = frame[frame['parameter'] == 'body_dynamics.central_field_deg']
    row = field[field['side'] == 'low'].iloc[0]
    assert row['d_c1_targets'] < 0 and row['value'] == pytest.approx(15.0)


# ------------------------------------------------------------------------------ bad options

@pytest.mark.parametrize('argv, words', [
    (['--low', '1.5'], '--low must be below 1'),
    (['--high', 'x'], '--high must be a positive number'),
    (['--subjects', '0'], '--subjects must be a whole number >= 1'),
    (['--subjects', '99'], '--subjects must be within 1..15'),
    (['--seeds', 'two'], '--seeds must be a whole number'),
    (['--parameters', 'reaction_delay.nonsense'],
     '--parameters: unknown or not swept reaction_delay.nonsense'),
    (['--exclude', 'nonsense'], '--exclude: unknown or not swept nonsense'),
    (['--speed-scene', 'no-such-scene'], 'no-such-scene'),
])
def test_bad_options_give_one_clear_line(tmp_path, argv, words):
    code, stdout, stderr = _main(['--out', str(tmp_path / 'o')] + argv)
    assert code == 2
    lines = stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith('fabric-guidance sensitivity: error: ')
    assert words in lines[0]
    assert not (tmp_path / 'o').exists()


def test_registered_as_a_subcommand(tmp_path):
    from fabric_guidance.commands import cli
    code = None
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        code = cli.main(['sensitivity', '--out', str(tmp_path), '--low', '0'])
    assert code == 2 and '--low must be a positive finite factor' in err.getvalue()
    assert math.isfinite(S.Settings().low)
