"""`fabric-guidance analyze TABLE.csv|STUDY_DIR`: the paper's statistics on a subjects x
conditions table, or on the one a live study's folder gives.

Prints the Friedman test, the Dunn-Bonferroni pairwise comparisons and the best condition per
subject; --plot writes the violin plot, --report a markdown report (embedding the plot if any).
A STUDY_DIR (docs/study.md) is read as the analysis of the headless experiment reads its trials:
the 'ok' rows of every sub-*/ses-*/*_task-<protocol>_trials.tsv, each participant's mean per
condition of each measure of the protocol (speed: identified targets per trial; accuracy: the
horizontal and the vertical error), one analysis per measure (--measure: one); --table writes
the subjects x conditions table. Exit status: 0 done, 2 bad table, folder or arguments, 1 an
output file could not be written.

Also runs alone: python -m fabric_guidance.experiments.analyze TABLE.csv
"""
from __future__ import annotations

import argparse
from pathlib import Path
import sys

import pandas as pd

from .. import subcommand
from ..atomic import write_text
from ..sim.protocols import CONDITION_NAMES, MEASURES
from .stats import analyze_blocks, analyze_trials, format_analysis, load_table

PROG = 'fabric-guidance analyze'
HELP = ('Friedman test + Dunn-Bonferroni post-hoc on a subjects x conditions CSV (as the paper\'s table) '
        'or on a live study\'s folder')
#: The study folder as study/store.py writes it (this layer sits below study/: the layout is
#: read here as any BIDS reader reads it; test_study_store checks both agree).
STUDY_DESCRIPTION = 'dataset_description.json'
STUDY_FORMAT = ('FabricGuidanceStudyFormat', 1)
STUDY_TRIALS = 'sub-*/ses-*/sub-*_ses-*_task-*_trials.tsv'


def configure(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    parser.add_argument('table', type=Path, metavar='TABLE.csv|STUDY_DIR',
                        help='header row, then one row per subject: subject id, one value per condition; '
                             'or a study folder')
    parser.add_argument('--lower-is-better', action='store_true',
                        help='smaller values are better (errors, times): decides the best condition per subject '
                             '(a study folder: known per measure)')
    parser.add_argument('--protocol', choices=sorted(MEASURES),
                        help='a study folder: the task to analyse (default: the only one it holds)')
    parser.add_argument('--measure', help='a study folder: only this measure (a column of its trials)')
    parser.add_argument('--table', dest='table_out', type=Path, metavar='OUT.csv',
                        help="a study folder: write the subjects x conditions table (one per measure: "
                             "OUT-<measure>.csv when several)")
    parser.add_argument('--plot', type=Path, metavar='OUT.png', help='write the violin plot here')
    parser.add_argument('--label', default=None,
                        help='y-axis label of the plot (default: "<table name> (per subject)")')
    parser.add_argument('--report', type=Path, metavar='OUT.md', help='write a markdown report here')
    return parser


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add the `analyze` subcommand to an argparse subparsers object; dispatch to run(args)."""
    return subcommand.add(subparsers, 'analyze', HELP, __doc__, configure, run)


def study_frame(root: Path, protocol: str | None = None):
    """The 'ok' trials of a study folder as a DataFrame (subject: the participant id, condition:
    the names experiments.stats uses) and the protocol; ValueError in one line."""
    import json
    path = root / STUDY_DESCRIPTION
    try:
        description = json.loads(path.read_text(encoding='utf-8'))
    except FileNotFoundError:
        raise ValueError(f'{root}: not a study folder (no {STUDY_DESCRIPTION}) and not a table') from None
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise ValueError(f'{path}: cannot read: {getattr(exc, "strerror", None) or exc}') from None
    key, version = STUDY_FORMAT
    if not isinstance(description, dict) or description.get(key) != version:
        found = description.get(key) if isinstance(description, dict) else None
        raise ValueError(f'{path}: study format version {found!r}, this fabric_guidance reads version {version}')
    frames = []
    for trials in sorted(root.glob(STUDY_TRIALS)):
        try:
            frames.append(pd.read_csv(trials, sep='\t', na_values=['n/a'], keep_default_na=False,
                                      dtype={'wearer': str, 'status': str, 'protocol': str}))
        except (OSError, ValueError) as exc:
            raise ValueError(f'{trials}: cannot read: {getattr(exc, "strerror", None) or exc}') from None
    if not frames:
        raise ValueError(f'{root}: no trials yet (no {STUDY_TRIALS})')
    data = pd.concat(frames, ignore_index=True)
    data = data[data['status'] == 'ok']
    protocols = sorted(set(data['protocol']))
    if protocol is None:
        if len(protocols) != 1:
            raise ValueError(f'{root}: holds the tasks {", ".join(protocols) or "none"}: choose one with --protocol')
        protocol = protocols[0]
    data = data[data['protocol'] == protocol].copy()
    if not len(data):
        raise ValueError(f'{root}: no finished {protocol} trials')
    data['subject'] = data['wearer']
    data['condition'] = data['condition'].map(CONDITION_NAMES)
    return data.reset_index(drop=True), protocol


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
    """analyze STUDY_DIR: one analysis per measure of the study's protocol."""
    try:
        data, protocol = study_frame(args.table, args.protocol)
        measures = MEASURES[protocol]
        if args.measure is not None:
            if args.measure not in data.columns:
                raise ValueError(f'--measure: {args.measure} is not a column of the trials')
            measures = {args.measure: measures.get(args.measure, not args.lower_is_better)}
        analyses = {m: analyze_trials(data, m, higher_is_better=hib) for m, hib in measures.items()}
    except ValueError as exc:
        subcommand.error(PROG, exc)
        return 2
    several = len(analyses) > 1

    def out(path: Path | None, measure: str) -> Path | None:
        return None if path is None else (path.with_name(f'{path.stem}-{measure}{path.suffix}') if several else path)

    plots = {}
    try:
        for measure, analysis in analyses.items():
            print(f'{protocol}: {measure}, per participant mean over their finished trials '
                  f'({len(analysis.table)} participants)')
            print(format_analysis(analysis), end='', flush=True)
            if args.table_out is not None:
                table = out(args.table_out, measure)
                write_text(table, analysis.table.rename_axis('subject').to_csv())
                print(f'table: {table}')
            if args.plot is not None:
                from .violin_plots import violin_plot
                plots[measure] = violin_plot(analysis, f'{measure} (per participant)', out(args.plot, measure),
                                             significance=analysis)
                print(f'plot: {plots[measure]}')
            print()
        write_report(args, f'Statistics of the study {args.table.name} ({protocol})',
                     {f'{m} (per participant)': a for m, a in analyses.items()},
                     {f'{m} (per participant)': p for m, p in plots.items()})
    except OSError as exc:
        subcommand.error(PROG, f'cannot write {exc.filename or "output"}: {exc.strerror or exc}')
        return 1
    return 0


def run(args: argparse.Namespace) -> int:
    if args.table.is_dir():
        return run_study(args)
    try:
        table = load_table(args.table)
        analysis = analyze_blocks(table, higher_is_better=not args.lower_is_better)
    except (ValueError, OSError) as exc:  # OSError: no such file, unreadable, a directory
        subcommand.error(PROG, exc if isinstance(exc, ValueError)
                         else f'{args.table}: {exc.strerror or exc}')
        return 2
    print(format_analysis(analysis), end='', flush=True)
    label = args.label or f'{args.table.stem} (per subject)'
    try:
        plot = None
        if args.plot is not None:
            from .violin_plots import violin_plot  # matplotlib only when a plot is asked for
            plot = violin_plot(analysis, label, args.plot, significance=analysis)
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
