"""Every plot the package makes, rendered from a small run and read as a reader would: axis
labels with their units (the trial's length for targets per trial), the conditions under the
names of core/plot_style.py, no two texts overlapping and no legend over data
(core/plot_style.py measures matplotlib's text extents), and intervals within a quantity's range.

Each run is the smallest that draws the plot (seconds); the figures are caught as they are saved.
"""
from __future__ import annotations

import contextlib
import io
import os
from pathlib import Path
import re

from matplotlib.collections import LineCollection
from matplotlib.figure import Figure
import numpy as np
import pytest
import yaml

from fabric_guidance.core.plot_style import (condition_label, legends_covering_data, measure_label,
                                             overlapping_texts)
from fabric_guidance.paths import config_path

DATA = Path(__file__).parent / 'data'
#: A unit in parentheses at the end of a label, or a count per trial.
UNIT = re.compile(r'\([^()]*\b(deg|s|ms|min|kPa|MB|Hz|count|x)\b[^()]*\)|per .*trial')


@contextlib.contextmanager
def caught_figures():
    """{file name: Figure} of every figure saved inside the block."""
    saved: dict[str, Figure] = {}
    original = Figure.savefig

    def savefig(self, fname, *args, **kwargs):
        name = getattr(fname, 'name', fname)
        if isinstance(name, int):       # atomic_write's os.fdopen: the descriptor's file
            name = os.readlink(f'/proc/self/fd/{name}')
        name = Path(str(name)).name
        match = re.match(r'^\.(.+?)\.[^.]+\.tmp$', name)     # atomic_write's temporary file
        saved[match.group(1) if match else name] = self
        return original(self, fname, *args, **kwargs)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(Figure, 'savefig', savefig)
        yield saved


def quiet(main, argv):
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        return main(argv)


def readable(fig: Figure) -> None:
    """No two texts overlap, none runs off the figure, no legend lies over data."""
    problems = overlapping_texts(fig) + legends_covering_data(fig)
    assert not problems, '\n'.join(problems)


def intervals(ax) -> np.ndarray:
    """The ends of every bar (LineCollection) of the axes, in data coordinates (x, y)."""
    ends = [np.asarray(seg, float) for c in ax.collections if isinstance(c, LineCollection)
            for seg in c.get_segments() if len(seg)]
    return np.concatenate(ends) if ends else np.empty((0, 2))


def within_axes(ax) -> None:
    """Every bar lies inside the axes' limits (none cut by the frame), and a log axis has no
    bar end at or below 0."""
    ends = intervals(ax)
    (x0, x1), (y0, y1) = sorted(ax.get_xlim()), sorted(ax.get_ylim())
    eps_x, eps_y = 1e-9 * (x1 - x0), 1e-9 * (y1 - y0)
    assert np.all((ends[:, 0] >= x0 - eps_x) & (ends[:, 0] <= x1 + eps_x)), f'{ax.get_title()}: a bar leaves the x axis'
    assert np.all((ends[:, 1] >= y0 - eps_y) & (ends[:, 1] <= y1 + eps_y)), f'{ax.get_title()}: a bar leaves the y axis'


def never_below_zero(ax, columns=(0, 1)) -> None:
    """No bar end below 0 on the axes of positive quantities (columns: 0 x, 1 y)."""
    ends = intervals(ax)[:, list(columns)]
    assert ends.size and np.all(ends >= 0), f'{ax.get_title()!r}: an interval reaches below 0 ({ends.min():g})'


def tick_texts(ax) -> list[str]:
    return [t.get_text().replace('\n', ' ') for t in ax.get_xticklabels()]


def legend_texts(fig: Figure) -> list[str]:
    legends = [ax.get_legend() for ax in fig.axes if ax.get_legend()] + list(fig.legends)
    return [t.get_text() for lg in legends for t in lg.get_texts()]


# ---------------------------------------------------------------- the checks themselves

def test_the_checks_see_overlapping_texts_a_text_off_the_figure_and_a_legend_over_data():
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from fabric_guidance.core.plot_style import legend_clear
    fig = Figure(figsize=(4, 3))
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    ax.plot([0, 1, 2], [0, 1, 2], 'o-', label='data')
    assert overlapping_texts(fig) == [] and legends_covering_data(fig) == []
    ax.text(1.0, 1.5, 'one label')
    ax.text(1.05, 1.52, 'another label')
    ax.text(1.9, 0.2, 'a long note that runs past the right edge of the figure')
    problems = overlapping_texts(fig)
    assert any("'one label' overlaps text 'another label'" in p for p in problems), problems
    assert any('runs off the figure' in p for p in problems), problems
    ax.legend(loc='center', fontsize=20)        # over the middle point
    assert legends_covering_data(fig)
    legend_clear(ax)                            # moved where it covers nothing
    assert not legends_covering_data(fig)


def test_labels_and_ranges():
    from fabric_guidance.core.plot_style import quantile_interval, within_range, with_unit
    assert measure_label('identified', 10.0) == 'identified target objects per 10 s trial'
    assert measure_label('identified') == 'identified target objects per trial'
    assert measure_label('h_error_deg', per='mean per participant') == \
        'horizontal error at the key press (deg), mean per participant'
    assert with_unit('threads', 'count') == 'threads (count)' and with_unit('G', '-') == 'G'
    assert condition_label(3) == '3 simple (arm) haptics, adjusted'
    assert within_range(-2.0, 5.0) == (0.0, 5.0, True) and within_range(1.0, 5.0) == (1.0, 5.0, False)
    lo, hi = quantile_interval([0.1, 0.2, 0.3, 10.0])
    assert 0.1 <= lo < hi <= 10.0


# ---------------------------------------------------------------- experiment and analyze

@pytest.fixture(scope='module')
def experiment_run(tmp_path_factory):
    """experiment on a study's scene file: paper-speed with 10 s trials, two repetitions,
    written as `study --simulated` writes it (the name inside still paper-speed)."""
    from fabric_guidance.commands import cli
    tmp = tmp_path_factory.mktemp('plots-experiment')
    data = yaml.safe_load(Path(config_path('scenes/paper-speed.yaml')).read_text())
    data['protocol']['trial_s'] = 10.0
    data['repetitions'] = 2
    scene = tmp / 'scene-speed.yaml'
    scene.write_text(yaml.safe_dump(data, sort_keys=False))
    with caught_figures() as figures:
        code = quiet(cli.main, ['experiment', '--scene', str(scene), '--subjects', '3', '--workers', '1',
                                '--out', str(tmp / 'out')])
    assert code == 0
    return tmp / 'out', figures


def test_experiment_names_the_scene_file_and_its_trial_length(experiment_run):
    _, figures = experiment_run
    ax = figures['identified.png'].axes[0]
    assert ax.get_ylabel() == measure_label('identified', 10.0)
    assert 'per 10 s trial' in ax.get_ylabel() and '40' not in ax.get_ylabel()
    title = ax.get_title()
    assert 'scene-speed.yaml' in title and not title.startswith('paper-speed')


def test_identified_names_its_dots_and_its_conditions_and_shows_no_key_without_stars(experiment_run):
    _, figures = experiment_run
    fig = figures['identified.png']
    ax = fig.axes[0]
    assert tick_texts(ax) == [condition_label(c) for c in (1, 2, 3, 4)]
    assert any('trial' in t for t in legend_texts(fig)), legend_texts(fig)
    stars = [t for t in ax.texts if set(t.get_text()) <= {'*'}]
    assert not stars and 'p < 0.05' not in ax.get_xlabel()    # 3 wearers: no pair apart
    readable(fig)


def test_analyze_labels_a_measure_with_its_unit_not_its_column_or_file(experiment_run, tmp_path):
    from fabric_guidance.experiments import analyze
    out, _ = experiment_run
    with caught_figures() as figures:
        assert quiet(analyze.main, [str(out / 'trials.csv'), '--plot', str(tmp_path / 'trials.png')]) == 0
        assert quiet(analyze.main, [str(DATA / 'table-identified-targets.csv'),
                                    '--plot', str(tmp_path / 'table.png')]) == 0
    trials, table = figures['trials.png'], figures['table.png']
    assert trials.axes[0].get_ylabel() == measure_label('identified', None, 'mean per participant')
    assert 'table-identified-targets' not in table.axes[0].get_ylabel()
    assert 'per subject' in table.axes[0].get_ylabel()
    for fig in (trials, table):
        assert tick_texts(fig.axes[0]) == [condition_label(c) for c in (1, 2, 3, 4)]
        readable(fig)
    # the paper's table separates conditions 1 and 4: brackets, and the key that reads them
    assert any(set(t.get_text()) <= {'*'} for t in table.axes[0].texts)
    assert 'p < 0.05' in table.axes[0].get_xlabel()


def test_analyze_of_a_study_folder_says_its_trial_length(tmp_path):
    from fabric_guidance.experiments import analyze
    from test_study_store import DESIGN, run_participant
    for pid in ('P1', 'P2', 'P3'):
        run_participant(tmp_path / 'study', pid)
    with caught_figures() as figures:
        assert quiet(analyze.main, [str(tmp_path / 'study'), '--plot', str(tmp_path / 'study.png')]) == 0
    fig = figures['study.png']
    assert fig.axes[0].get_ylabel() == measure_label('identified', DESIGN.trial_s, 'mean per participant')
    assert f'per {DESIGN.trial_s:g} s trial' in fig.axes[0].get_ylabel()
    readable(fig)


def test_beyond_violins_say_the_trial_length_and_are_readable(tmp_path):
    from fabric_guidance.experiments.discussion import beyond
    with caught_figures() as figures:
        assert quiet(beyond.main, ['--quick', '--workers', '1', '--out', str(tmp_path)]) == 0
    assert len(figures) == 9
    scene = yaml.safe_load(Path(config_path('scenes/paper-speed.yaml')).read_text())     # beyond's default
    assert figures['gain_identified.png'].axes[0].get_ylabel() == measure_label(
        'identified', scene['protocol']['trial_s'], 'mean per wearer')
    for fig in figures.values():
        assert UNIT.search(fig.axes[0].get_ylabel()), fig.axes[0].get_ylabel()
        readable(fig)


# ---------------------------------------------------------------- tradeoff

@pytest.fixture(scope='module')
def tradeoff_run(tmp_path_factory):
    """The --quick sweep over 2 seeds on three knobs (the gain on its full grid of seven values,
    the two knobs whose errors lie near 0), written as the command writes it."""
    from fabric_guidance.experiments.tradeoff.intervals import run_seeds
    from fabric_guidance.experiments.tradeoff.report import write_outputs
    from fabric_guidance.experiments.tradeoff.settings import DEFAULT_GRIDS, QUICK_GRIDS, base_scenes, quick_settings
    settings = quick_settings(knobs=('gain', 'acceptance_deg', 'fit_tolerance'), workers=1,
                              grids={**QUICK_GRIDS, 'gain': DEFAULT_GRIDS['gain']})
    seed = base_scenes(settings)[1].seed
    with caught_figures() as figures:
        write_outputs(run_seeds(settings, (seed, seed + 1)), tmp_path_factory.mktemp('plots-tradeoff'))
    return figures


GAINS = [0.0, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5]


@pytest.mark.parametrize('name', ['gain.png', 'acceptance_deg.png', 'fit_tolerance.png'])
def test_knob_plots_are_readable_with_whiskers_within_range(tradeoff_run, name):
    fig = tradeoff_run[name]
    readable(fig)
    for ax in fig.axes:
        never_below_zero(ax)
        within_axes(ax)
        assert UNIT.search(ax.get_xlabel()) and UNIT.search(ax.get_ylabel()), (ax.get_xlabel(), ax.get_ylabel())


def test_gain_plot_labels_every_value(tradeoff_run):
    from fabric_guidance.experiments.tradeoff.settings import DEFAULT_GRIDS
    assert list(DEFAULT_GRIDS['gain']) == GAINS
    for ax in tradeoff_run['gain.png'].axes:
        texts = ' '.join(t.get_text() for t in ax.texts)
        for g in GAINS:
            assert re.search(rf'G = ([\d.]+, )*{g:g}(?![\d.])', texts), (g, texts)
        assert 'not labelled' not in texts


def test_plane_zoom_cuts_no_whisker_and_labels_every_gain(tradeoff_run):
    fig = tradeoff_run['plane.png']
    readable(fig)
    whole, zoom = fig.axes[:2]
    for ax in (whole, zoom):
        within_axes(ax)
        never_below_zero(ax)
        assert UNIT.search(ax.get_xlabel()) and UNIT.search(ax.get_ylabel())
    labels = ' '.join(t.get_text() for t in zoom.texts)
    for g in GAINS:
        if g != 0.05:       # the package's gain: the condition's own point
            assert re.search(rf'G ([\d.]+, )*{g:g}(?![\d.])', labels), (g, labels)
    assert 'not labelled' not in labels
    for c in (1, 2, 3, 4):
        assert any(condition_label(c) in t for t in legend_texts(fig)), legend_texts(fig)


# ---------------------------------------------------------------- sensitivity, compare-paper, fit_tradeoff

def test_sensitivity_axes_have_labels_with_units(tmp_path):
    from fabric_guidance.experiments import sensitivity
    with caught_figures() as figures:
        assert quiet(sensitivity.main, ['--quick', '--parameters', 'reaction_delay.mean_s,gaze_noise.sd_deg',
                                        '--workers', '1', '--out', str(tmp_path)]) == 0
    fig = figures['sensitivity.png']
    readable(fig)
    labels = [ax.get_xlabel().replace('\n', ' ') for ax in fig.axes]
    assert all(UNIT.search(x) for x in labels), labels
    # the targets are per 40 s whatever the trials' length (--quick: 20 s, scaled)
    assert sum('per 40 s trial' in x for x in labels) == 3 and sum('(deg' in x for x in labels) == 2, labels
    titles = [ax.get_title().replace('\n', ' ') for ax in fig.axes]
    assert titles[0] == f'condition {condition_label(1)}' and titles[2] == f'condition {condition_label(4)}'
    for ax, label in zip(fig.axes, labels):
        if 'difference' not in label:       # targets and errors: never below 0, nor their bands
            assert ax.get_xlim()[0] >= 0 and all(p.get_x() >= 0 for p in ax.patches if hasattr(p, 'get_x'))


def test_comparison_bars_stay_in_the_axes_and_conditions_are_named_as_elsewhere(tmp_path):
    from fabric_guidance.experiments import paper_comparison
    with caught_figures() as figures:
        assert quiet(paper_comparison.main, ['--out', str(tmp_path), '--speed-scene', 'paper-speed',
                                             '--accuracy-scene', 'paper-accuracy', '--subjects', '3',
                                             '--seeds', '7', '--workers', '1']) == 0
    fig = figures['comparison.png']
    readable(fig)
    for ax in fig.axes:
        assert tick_texts(ax) == [condition_label(c) for c in (1, 2, 3, 4)]
        assert UNIT.search(ax.get_ylabel()), ax.get_ylabel()
        within_axes(ax)
        never_below_zero(ax, columns=(1,))      # x: the conditions


def test_fit_tradeoff_uses_one_axis_for_the_weight_and_says_what_each_line_is(tmp_path):
    from fabric_guidance.experiments import fit_tradeoff
    design = config_path('scenes/fit') / 'design-arm_spread-0.1.npz'
    with caught_figures() as figures:
        assert quiet(fit_tradeoff.main, ['--out', str(tmp_path), '--emphasis', '1,2,8', '--draws', '20',
                                         '--design', str(design)]) == 0
    fig = figures['fit_tradeoff.png']
    readable(fig)
    a, b = fig.axes[:2]
    assert a.get_xscale() == b.get_xscale()
    assert [t.get_text() for t in a.get_xticklabels()] == [t.get_text() for t in b.get_xticklabels()]
    assert not {'means', 'sds', 'best', 'corr'} & set(legend_texts(fig)), legend_texts(fig)


# ---------------------------------------------------------------- lab and bench

def test_calibration_report_figure(tmp_path):
    from fabric_guidance.lab import calibration_report
    with caught_figures() as figures:
        assert quiet(calibration_report.main, [str(config_path('calibrations/sim-wearer.yaml')),
                                               '--out', str(tmp_path)]) == 0
    fig = figures['sim-wearer-fit.png']
    readable(fig)
    for ax in fig.axes:
        if ax.axison:
            assert UNIT.search(ax.get_ylabel().replace('\n', ' ')), ax.get_ylabel()
    # a refused direction's note (bottom right) and the legend keep apart
    import dataclasses
    from fabric_guidance.core.calibration import Calibration
    cal = Calibration.load(config_path('calibrations/sim-wearer.yaml'))
    directions = dict(cal.directions)
    directions['left'] = dataclasses.replace(directions['left'], fit=dict(
        directions['left'].fit, refused='fit refused: angle span 0.3 deg < min_span_deg 5 deg'))
    readable(calibration_report.draw_fit_figure(dataclasses.replace(cal, directions=directions)))


def test_soak_figure(tmp_path):
    from fabric_guidance.bench.soak import COLUMNS, OBSERVED
    from fabric_guidance.bench.soak_report import plot
    rng = np.random.default_rng(1)
    rows = []
    for i in range(6):
        row = {c: 0 for c in COLUMNS}
        row.update(row=i, t_start_s=60.0 * i, t_end_s=60.0 * (i + 1), warnings='', stall='',
                   targets_reached=20, targets_skipped=1, time_to_target_s=2.5)
        for kind in ('latency', 'command'):
            row.update({f'{kind}_p50_ms': 2 + rng.random(), f'{kind}_p99_ms': 6 + rng.random(),
                        f'{kind}_max_ms': 12 + 3 * rng.random()})
        for n in OBSERVED:
            row.update({f'rss_mb.{n}': 80 + rng.random(), f'cpu_s_per_min.{n}': 3 * rng.random(),
                        f'fds.{n}': 20, f'threads.{n}': 10})
        rows.append(row)
    with caught_figures() as figures:
        plot(rows, tmp_path / 'soak.png', OBSERVED)
    fig = next(iter(figures.values()))
    readable(fig)
    for ax in fig.axes:
        assert UNIT.search(ax.get_ylabel()), ax.get_ylabel()
