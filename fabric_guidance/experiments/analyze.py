"""`fabric-guidance analyze TABLE.csv|TRIALS.csv|STUDY_DIR`: the paper's statistics on a subjects x
conditions table, on the trials table `experiment` writes (trials.csv: each wearer's mean per
condition of each measure of its protocol, as the experiment analysed it), or on the table a
live study's folder gives.

Prints the Friedman test, the Dunn-Bonferroni pairwise comparisons and the best condition per
subject; --plot writes the violin plot, --report a markdown report (embedding the plot if any).
A STUDY_DIR (docs/study.md) is read as the analysis of the headless experiment reads its trials:
the trials that ended of every sub-*/ses-*/beh/*_task-<protocol>_beh.tsv (study_folder.py: 'ok'
rows of blocks listed done, each value range-checked), each participant's mean per condition of
each measure of the protocol (speed: identified targets per trial; accuracy: the horizontal and
the vertical error), one analysis per measure (--measure: one; each measure knows whether lower
is better); a participant without every condition is left out and named, one participant is
reported without the tests; --table writes the subjects x conditions table. Exit status: 0
done, 2 bad table, folder or arguments, 1 an output file could not be written.

Also runs alone: python -m fabric_guidance.experiments.analyze TABLE.csv
"""
from __future__ import annotations

import argparse
from pathlib import Path
import sys

import pandas as pd

from .. import subcommand
from ..atomic import write_text
from ..sim.protocols import MEASURES
from .stats import analyze_blocks, analyze_trials, condition_label, format_analysis, load_table
from .study_folder import HIGHER_IS_BETTER, TRIALS_GLOB, complete, read_study

PROG = 'fabric-guidance analyze'
HELP = ('Friedman test + Dunn-Bonferroni post-hoc on a subjects x conditions CSV (as the paper\'s table) '
        'or on a live study\'s folder')
#: The study folder as study/store.py writes it (study_folder.py reads it).
STUDY_TRIALS = TRIALS_GLOB


def configure(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    parser.add_argument('table', type=Path, metavar='TABLE.csv|TRIALS.csv|STUDY_DIR',
                        help='header row, then one row per subject: subject id, one value per condition; '
                             "or experiment's trials.csv; or a study folder")
    parser.add_argument('--lower-is-better', action='store_true',
                        help='smaller values are better (errors, times): decides the best condition per subject '
                             '(a study folder: known per measure)')
    parser.add_argument('--protocol', choices=sorted(MEASURES),
                        help='a study folder or trials table: the task to analyse (default: the only one it holds)')
    parser.add_argument('--measure', help='a study folder or trials table: only this measure (a column of its '
                                          "trials); a table: the measure its values are (the plot's label)")
    parser.add_argument('--table', dest='table_out', type=Path, metavar='OUT.csv',
                        help="a study folder: write the subjects x conditions table (one per measure: "
                             "OUT-<measure>.csv when several)")
    parser.add_argument('--plot', type=Path, metavar='OUT.png', help='write the violin plot here')
    parser.add_argument('--label', default=None,
                        help="y-axis label of the plot (default: the measure with its unit; a table without "
                             "--measure: a value per subject in the table's unit)")
    parser.add_argument('--report', type=Path, metavar='OUT.md', help='write a markdown report here')
    return parser


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add the `analyze` subcommand to an argparse subparsers object; dispatch to run(args)."""
    return subcommand.add(subparsers, 'analyze', HELP, __doc__, configure, run)


def study_frame(root: Path, protocol: str | None = None):
    """The trials of a study folder that count (study_folder.read_study) as a DataFrame and the
    protocol; ValueError in one line."""
    data = read_study(root, protocol)
    return data.frame, data.protocol


def write_report(args: argparse.Namespace, title: str, analyses: dict, plots: dict) -> None:
    """The markdown report at --report, if asked for (a table's or a study's analyses)."""
    if args.report is None:
        return
    from .analysis_report import markdown_report
    text = markdown_report(title, analyses, plots, notes=[f'Source: {args.table}'],
                           relative_to=args.report.parent)
    write_text(args.report, text)
    print(f'report: {args.report}')


def run_study(args: argparse.Namespace) -> int:
    """analyze STUDY_DIR: one analysis per measure of the study's protocol; a participant
    without a finished trial in every condition is left out (named), one participant is
    reported without the tests."""
    try:
        data = read_study(args.table, args.protocol)
        protocol = data.protocol
        measures = {m: HIGHER_IS_BETTER[m] for m in MEASURES[protocol]}
        if args.measure is not None:
            measures = {args.measure: HIGHER_IS_BETTER.get(args.measure, not args.lower_is_better)}
        tables = {m: complete(data, m) for m in measures}
        for m, (frame, _) in tables.items():
            if frame.empty:
                raise ValueError(f'{args.table}: no participant has a finished trial with a {m} in every condition '
                                 f'({"; ".join(tables[m][1][-3:])})')
        analyses = {m: analyze_trials(frame, m, higher_is_better=measures[m], conditions=data.conditions)
                    if frame['subject'].nunique() > 1 else one_participant(frame, m, data.conditions)
                    for m, (frame, _) in tables.items()}
    except ValueError as exc:
        subcommand.error(PROG, exc)
        return 2
    for note in data.notes:
        print(f'left out: {note}')
    return write_analyses(args, protocol, measures, analyses, {m: notes for m, (_, notes) in tables.items()},
                          f'Statistics of the study {args.table.name} ({protocol})', data.trial_s)


def write_analyses(args: argparse.Namespace, protocol: str, measures: dict, analyses: dict, notes: dict,
                   title: str, trial_s: float | None = None) -> int:
    """Print each measure's analysis (a one-participant table without tests), and write the
    --table, --plot and --report outputs; 1 when an output cannot be written. trial_s: the
    trials' length where the source says it (the label of targets per trial)."""
    from ..core.plot_style import measure_label
    several = len(analyses) > 1
    labels = {m: args.label or measure_label(m, trial_s, 'mean per participant') for m in analyses}

    def out(path: Path | None, measure: str) -> Path | None:
        return None if path is None else (path.with_name(f'{path.stem}-{measure}{path.suffix}') if several else path)

    plots = {}
    try:
        for measure, analysis in analyses.items():
            for note in notes.get(measure, ()):
                print(f'left out: {note}')
            direction = 'higher' if measures[measure] else 'lower'
            if isinstance(analysis, pd.DataFrame):
                print(f'{protocol}: {measure}, per participant mean over their finished trials (1 participant: '
                      f'the Friedman test needs at least 2); {direction} is better')
                print(analysis.rename(columns=condition_label).to_string(float_format=lambda v: f'{v:.3f}'))
                table = analysis
            else:
                print(f'{protocol}: {measure}, per participant mean over their finished trials '
                      f'({len(analysis.table)} participants)')
                print(format_analysis(analysis), end='', flush=True)
                table = analysis.table
            if args.table_out is not None:
                path = out(args.table_out, measure)
                write_text(path, table.rename_axis('subject').to_csv())
                print(f'table: {path}')
            if args.plot is not None and not isinstance(analysis, pd.DataFrame):
                from .violin_plots import violin_plot
                plots[measure] = violin_plot(analysis, labels[measure], out(args.plot, measure),
                                             significance=analysis, title=f'{args.table.name} ({protocol})',
                                             point="one participant's mean")
                print(f'plot: {plots[measure]}')
            print()
        write_report(args, title,
                     {labels[m]: a for m, a in analyses.items() if not isinstance(a, pd.DataFrame)},
                     {labels[m]: p for m, p in plots.items()})
    except OSError as exc:
        subcommand.error(PROG, f'cannot write {exc.filename or "output"}: {exc.strerror or exc}')
        return 1
    return 0


def one_participant(frame: pd.DataFrame, measure: str, conditions) -> pd.DataFrame:
    """The subjects x conditions table of means of a single participant (no test is defined)."""
    table = frame.groupby(['subject', 'condition'])[measure].mean().unstack('condition')
    return table.reindex(columns=list(conditions))


#: The columns that make a CSV the trials table `experiment` writes (one row per trial).
TRIALS_COLUMNS = {'protocol', 'subject', 'condition', 'repetition'}


def is_trials_table(path: Path) -> bool:
    try:
        return TRIALS_COLUMNS <= set(pd.read_csv(path, nrows=0).columns)
    except (ValueError, OSError, pd.errors.ParserError):
        return False    # load_table says what is wrong with it


def run_trials(args: argparse.Namespace) -> int:
    """analyze TRIALS.csv, the trials table `experiment` writes: each wearer's mean per condition
    of each measure of the protocol, as the experiment analysed them."""
    try:
        frame = pd.read_csv(args.table)
        protocols = sorted(str(p) for p in frame['protocol'].dropna().unique())
        protocol = args.protocol or (protocols[0] if len(protocols) == 1 else None)
        if protocol not in MEASURES:
            raise ValueError(f'{args.table}: holds the protocols {", ".join(protocols) or "none"}: '
                             'give --protocol')
        frame = frame[frame['protocol'] == protocol].copy()
        if 'wearer' in frame:
            frame['subject'] = frame['wearer']   # as experiment names them (S01, ...)
        measures = dict(MEASURES[protocol])
        if args.measure is not None:
            if args.measure not in frame.columns:
                raise ValueError(f'--measure: {args.measure} is not a column of {args.table}')
            measures = {args.measure: HIGHER_IS_BETTER.get(args.measure, not args.lower_is_better)}
        analyses = {m: analyze_trials(frame, m, higher_is_better=h) for m, h in measures.items()}
    except (ValueError, KeyError) as exc:
        subcommand.error(PROG, f'{args.table}: {exc}' if str(args.table) not in str(exc) else exc)
        return 2
    return write_analyses(args, protocol, measures, analyses, {}, f'Statistics of {args.table.name} ({protocol})')


def run(args: argparse.Namespace) -> int:
    if args.table.is_dir():
        return run_study(args)
    if is_trials_table(args.table):
        return run_trials(args)
    try:
        table = load_table(args.table)
        analysis = analyze_blocks(table, higher_is_better=not args.lower_is_better)
    except (ValueError, OSError) as exc:  # OSError: no such file, unreadable, a directory
        subcommand.error(PROG, exc if isinstance(exc, ValueError)
                         else f'{args.table}: {exc.strerror or exc}')
        return 2
    print(format_analysis(analysis), end='', flush=True)
    from ..core.plot_style import measure_label
    label = args.label or (measure_label(args.measure, None, 'mean per subject') if args.measure
                           else "value per subject (the table's unit)")
    try:
        plot = None
        if args.plot is not None:
            from .violin_plots import violin_plot  # matplotlib only when a plot is asked for
            plot = violin_plot(analysis, label, args.plot, significance=analysis, title=args.table.name,
                               point="one subject's value")
            print(f'\nplot: {plot}')
        write_report(args, f'Statistics of {args.table.name}', {label: analysis},
                     {label: plot} if plot is not None else {})
    except OSError as exc:
        subcommand.error(PROG, f'cannot write {exc.filename or "output"}: {exc.strerror or exc}')
        return 1
    return 0


def main(argv: list[str] | None = None) -> int:
    return subcommand.main(PROG, __doc__, configure, run, argv)


if __name__ == '__main__':
    sys.exit(main())
