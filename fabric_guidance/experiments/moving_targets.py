"""The moving-target study's analysis, plots, summary and report section (`fabric-guidance
beyond`, experiments/beyond.py): targets moving at 5, 10, 20 deg/s under Eq. 5 as the paper
built it (theta_t taken once), Eq. 5 on the live target, and core.feedback's follow_target;
time to find and tracking error, with the target visible and not; how the simulation runs it:
sim/moving_targets.py."""
from __future__ import annotations

from pathlib import Path

import pandas as pd

from .arms import analyze_arms, pair_p
from .report import analysis_markdown, image_path, md_table
from .stats import format_p

LAW_NAMES = {'paper': 'paper: theta_t at start', 'live': 'live theta_t, no shift', 'follow': 'follow_target'}
MOVING_MEASURES = {'find_s': 'time to find (s)', 'tracking_error_deg': 'tracking error (deg)'}


def analyze_moving(results, out: dict) -> None:
    """The moving-target analyses of a StudyResults, into the parts dict `out`."""
    moving = results.moving_frame()
    out['moving_trials'] = moving
    out['moving'] = {}
    if not moving.empty:
        for scenario in results.settings.scenarios:
            for speed in results.settings.speeds_dps:
                part = moving[(moving['scenario'] == scenario) & (moving['speed_dps'] == float(speed))].copy()
                part['condition'] = part['law'].map(LAW_NAMES)
                for measure in MOVING_MEASURES:
                    out['moving'][(scenario, float(speed), measure)] = analyze_arms(part, measure, False,
                                                                                    LAW_NAMES.values())


def moving_plots(parts: dict, out: Path, plots: dict) -> None:
    from .plots import violin_plot
    for (scenario, speed, measure), a in parts['moving'].items():
        if a is None:
            continue
        name = f'moving_{scenario}_{speed:g}dps_{measure}.png'
        plots[(scenario, speed, measure)] = violin_plot(
            a, f'{MOVING_MEASURES[measure]} (per wearer)', out / name, significance=a,
            title=f'Target moving {speed:g} deg/s, {scenario}: {MOVING_MEASURES[measure]}')


def moving_summary(results, parts: dict, lines: list[str]) -> None:
    """The moving-target findings as plain sentences with their numbers, appended to `lines`."""
    for scenario in results.settings.scenarios:
        for speed in results.settings.speeds_dps:
            bits = []
            for measure, unit in (('find_s', 's'), ('tracking_error_deg', 'deg')):
                a = parts['moving'].get((scenario, float(speed), measure))
                if a is None:
                    continue
                m = a.summary['mean']
                p = pair_p(a, LAW_NAMES['paper'], LAW_NAMES['follow'])
                p_live = pair_p(a, LAW_NAMES['live'], LAW_NAMES['follow'])
                bits.append(f'{MOVING_MEASURES[measure].split(" (")[0]} paper {m[LAW_NAMES["paper"]]:.2f} / live '
                            f'{m[LAW_NAMES["live"]]:.2f} / follow {m[LAW_NAMES["follow"]]:.2f} {unit} '
                            f'(Friedman p = {format_p(a.p)}; follow vs paper p = {format_p(p)}, '
                            f'vs live p = {format_p(p_live)})')
            if bits:
                lines.append(f'Moving target {speed:g} deg/s, {scenario}: ' + '; '.join(bits) + '.')


def _found_table(moving: pd.DataFrame) -> list[str]:
    rows = []
    for (scenario, speed), part in moving.groupby(['scenario', 'speed_dps'], sort=False):
        row = [scenario, f'{speed:g}']
        for law in LAW_NAMES:
            g = part[part['law'] == law]
            per = g.groupby('subject')
            row.append(f'{100 * g["found"].mean():.0f} % / {per["find_s"].mean().mean():.2f} s / '
                       f'{per["tracking_error_deg"].mean().mean():.1f} / {per["late_error_deg"].mean().mean():.1f}')
        rows.append(row)
    return md_table(['target', 'deg/s'] + [LAW_NAMES[k] for k in LAW_NAMES], rows, 'lr' + 'l' * len(LAW_NAMES))


def moving_report(results, parts: dict, plots: dict, out: Path) -> list[str]:
    """The report's section 2 (markdown lines)."""
    sc, st = results.scene, results.settings
    doc = ['## 2. Moving targets', '',
           f'A target starts as a speed-protocol target (within +-{sc.protocol.horizontal_deg:g} deg horizontally, '
           f'+-{sc.protocol.vertical_deg:g} deg vertically) and moves at {", ".join(f"{s:g}" for s in st.speeds_dps)} '
           'deg/s (in the horizontal and vertical angles) in a random direction, reflected at the edges of that '
           f'range; {st.moving_reps} trials per speed, {st.moving_s:g} s each, guidance throughout (condition 1, the '
           f'scene\'s G = {sc.controller.gain:g}). The same targets and effect streams for the three laws:', '',
           f'- **{LAW_NAMES["paper"]}**: Eq. 5 as the paper built it for static targets: theta_t is taken once, '
           'when guidance begins.',
           f'- **{LAW_NAMES["live"]}**: Eq. 5 fed the moving target every control step, without the shift: what '
           'the pressure_controller node does with `follow_moving_target` false.',
           f'- **{LAW_NAMES["follow"]}**: the same with `follow_target`: a change of theta_t shifts the pressure by '
           'f(new) - f(old).', '',
           'Time to find: until the tracked gaze has first stayed within '
           f'{sc.protocol.acceptance_deg:g} deg of the moving target for {sc.protocol.dwell_s:g} s (censored at '
           f'{st.moving_s:g} s when never). Tracking error: angle between the true gaze and the target, mean over the '
           'trial. *seen*: the target is visible, the eyes catch it once it is in the central field (as in the speed '
           'protocol); *unseen*: no visual capture, the suit alone guides (as in the accuracy protocol).', '',
           'Per cell: found within the trial / mean time to find / mean tracking error (deg) / mean error over '
           'the second half (deg), means over wearers.', '']
    moving = parts.get('moving_trials')
    if moving is not None and not moving.empty:
        doc += _found_table(moving) + ['']
    for (scenario, speed, measure), a in parts['moving'].items():
        if a is None:
            continue
        doc += [f'### {speed:g} deg/s, {scenario}: {MOVING_MEASURES[measure]}', ''] + analysis_markdown(a, level=3)
        doc += ['']
        if (scenario, speed, measure) in plots:
            doc += [f'![{scenario} {speed:g} {measure}]({image_path(plots[(scenario, speed, measure)], out)})', '']
    return doc
