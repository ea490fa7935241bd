"""`fabric-guidance experiment`: one of the paper's subject experiments on simulated wearers.

    fabric-guidance experiment --protocol speed --subjects 15 --out results/speed
    fabric-guidance experiment --scene my-scene.yaml --out results/mine

Runs the protocol headless (every wearer calibrated by Algorithm 1, then the trials of every
condition in the wearer's own order), showing progress, and writes into OUT:

    trials.csv        one row per trial
    statistics.txt    the paper's statistics per measure (Friedman, Dunn-Bonferroni on ranks)
    <measure>.png     violin plots like the paper's figures
    report.md         the report: scene, exclusions, tables, statistics, plots
"""
from __future__ import annotations

import argparse
import os
from pathlib import Path
import sys
import time

from .. import subcommand
from ..atomic import write_csv, write_text

#: Per protocol: (measure column, label, higher is better), the paper's figures; {trial_s}: the
#: scene's trial length (the labels of statistics.txt and report.md; the plots' are plot_style's).
MEASURES = {
    'speed': [('identified', 'identified target objects per {trial_s:g} s trial', True)],
    'accuracy': [('h_error_deg', 'horizontal error [deg]', False), ('v_error_deg', 'vertical error [deg]', False)],
}


def scene_title(scene) -> str:
    """The scene as a reader finds it: a package scene (or an unchanged copy) by its name; a
    changed copy by its file, with the name it carries ('scene-speed.yaml, a changed
    paper-speed': a study's scene file keeps the name of the scene it was made from)."""
    from ..sim.scene import SceneError, load_scene, scene_names
    path = Path(scene.source)
    if scene.name in scene_names():
        try:
            if load_scene(scene.name).replace(source=scene.source) == scene:
                return scene.name
        except (SceneError, OSError):
            pass
        return f'{path.name}, a changed {scene.name}'
    return scene.name if path.stem == scene.name or not path.name else f'{path.name} ({scene.name})'


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser('experiment', help="run one of the paper's experiments on simulated wearers",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument('--protocol', choices=sorted(MEASURES), default=None,
                   help='the paper scene of this protocol on the fitted population '
                        '(config/scenes/paper-fitted-<protocol>.yaml, the README\'s figures); the '
                        'unfitted paper-<protocol> with --scene')
    p.add_argument('--scene', default=None, help='a scene file or a name in config/scenes (instead of --protocol)')
    p.add_argument('--subjects', type=int, default=None, help='the first N wearers of the scene (default: all)')
    p.add_argument('--workers', type=int, default=min(2, os.cpu_count() or 1), help='processes (default: 2)')
    p.add_argument('--out', type=Path, required=True, help='folder for the CSV, statistics, plots and report')
    p.add_argument('--overwrite', action='store_true',
                   help='write into an --out that holds files already (refused otherwise: two runs would mix)')
    return p


def run(args) -> int:
    from ..core.plot_style import measure_label
    from ..sim.protocols import format_summary, run_protocol, trials_frame
    from ..sim.scene import SceneError, load_scene
    from .violin_plots import violin_plot
    from .analysis_report import markdown_report
    from .stats import analyze_trials, format_analysis

    if (args.protocol is None) == (args.scene is None):
        print('fabric-guidance experiment: error: give exactly one of --protocol or --scene', file=sys.stderr)
        return 2
    try:
        scene = load_scene(args.scene or f'paper-fitted-{args.protocol}')
    except (SceneError, OSError) as exc:
        print(f'fabric-guidance experiment: error: {exc}', file=sys.stderr)
        return 2
    if args.subjects is not None and not 1 <= args.subjects <= scene.population.subjects:
        print(f'fabric-guidance experiment: error: --subjects must be 1..{scene.population.subjects} '
              f'(the scene\'s population)', file=sys.stderr)
        return 2
    out: Path = args.out
    why = subcommand.results_folder(out, args.overwrite)
    if why:
        print(f'fabric-guidance experiment: error: {why}', file=sys.stderr)
        return 2
    out.mkdir(parents=True, exist_ok=True)
    n = args.subjects or scene.population.subjects
    title = scene_title(scene)
    trial_s = getattr(scene.protocol, 'trial_s', None)
    print(f'scene {title}: {scene.protocol.kind} protocol, {n} wearers, conditions {list(scene.conditions)}, '
          f'{scene.repetitions} repetitions, effects: {", ".join(scene.effect_names) or "none"}', flush=True)
    started = time.monotonic()

    def progress(done, total, subject):
        print(f'  [{done:>2}/{total}] wearer {subject + 1:02d} calibrated and done '
              f'({time.monotonic() - started:5.1f} s)', flush=True)

    results = run_protocol(scene, subjects=n, workers=args.workers, progress=progress)
    summary = format_summary(scene, results)
    print(summary)
    frame = trials_frame(results)
    write_csv(out / 'trials.csv', frame)
    if len(frame):
        frame['subject'] = frame['wearer']   # statistics and plots name wearers (S01, ...)
    if len(frame) == 0:
        print('no wearer could be calibrated: nothing to analyse (see the exclusions above)', file=sys.stderr)
        return 1

    analyses, plots, texts = {}, {}, []
    for measure, label, higher in MEASURES[scene.protocol.kind]:
        label = label.format(trial_s=trial_s)
        try:
            analysis = analyze_trials(frame, measure, higher_is_better=higher)
        except ValueError as exc:      # e.g. fewer than 2 wearers or conditions left
            texts.append(f'{label}: no statistics ({exc})')
            continue
        analyses[label] = analysis
        texts.append(f'== {label} ==\n{format_analysis(analysis)}')
        plots[label] = violin_plot(frame, measure_label(measure, trial_s), out / f'{measure}.png',
                                   significance=analysis, measure=measure,
                                   title=f'{title}: {scene.protocol.kind} experiment')
    write_text(out / 'statistics.txt', '\n\n'.join(texts) + '\n')
    notes = [f'Scene `{title}`; effects: {", ".join(scene.effect_names) or "none (ideal wearer)"}.',
             f'{len({r.subject for r in results})} wearers analysed, {len(results.exclusions)} excluded.',
             *[f'Excluded {e.wearer}: {e.reason}' for e in results.exclusions],
             f'{results.sim_s:.0f} simulated seconds in {results.wall_s:.1f} wall seconds.',
             'Simulated wearers, not people: the numbers show what the model implies, not what a lab will measure.']
    report = markdown_report(f'{scene.protocol.kind.capitalize()} experiment in simulation: {title}',
                             analyses, plots, notes, relative_to=out)
    write_text(out / 'report.md', report)
    print('\n\n'.join(texts))
    print(f'\nwrote {out / "trials.csv"}, {out / "statistics.txt"}, {out / "report.md"} and '
          f'{len(plots)} plot(s) in {time.monotonic() - started:.1f} s')
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog='fabric-guidance')
    add_parser(parser.add_subparsers(dest='command', required=True))
    return run(parser.parse_args(['experiment', *(argv if argv is not None else sys.argv[1:])]))


if __name__ == '__main__':
    sys.exit(main())
