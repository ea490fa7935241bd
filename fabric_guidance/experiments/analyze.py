"""`fabric-guidance analyze TABLE.csv`: the paper's statistics on a subjects x conditions table.

Prints the Friedman test, the Dunn-Bonferroni pairwise comparisons and the best condition per
subject; --plot writes the violin plot, --report a markdown report (embedding the plot if any).
Exit status: 0 done, 2 bad table or arguments, 1 an output file could not be written.

Also runs alone: python -m fabric_guidance.experiments.analyze TABLE.csv
"""
from __future__ import annotations

import argparse
from pathlib import Path
import sys

from .. import subcommand
from ..atomic import write_text
from .stats import analyze_blocks, format_analysis, load_table

PROG = 'fabric-guidance analyze'
HELP = 'Friedman test + Dunn-Bonferroni post-hoc on a subjects x conditions CSV (as the paper\'s table)'


def configure(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    parser.add_argument('table', type=Path, metavar='TABLE.csv',
                        help='header row, then one row per subject: subject id, one value per condition')
    parser.add_argument('--lower-is-better', action='store_true',
                        help='smaller values are better (errors, times): decides the best condition per subject')
    parser.add_argument('--plot', type=Path, metavar='OUT.png', help='write the violin plot here')
    parser.add_argument('--label', default=None,
                        help='y-axis label of the plot (default: "<table name> (per subject)")')
    parser.add_argument('--report', type=Path, metavar='OUT.md', help='write a markdown report here')
    return parser


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add the `analyze` subcommand to an argparse subparsers object; dispatch to run(args)."""
    return subcommand.add(subparsers, 'analyze', HELP, __doc__, configure, run)


def run(args: argparse.Namespace) -> int:
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
        if args.report is not None:
            from .analysis_report import markdown_report
            text = markdown_report(f'Statistics of {args.table.name}', {label: analysis},
                                   {label: plot} if plot is not None else {},
                                   notes=[f'Source: {args.table}'], relative_to=args.report.parent)
            write_text(args.report, text)
            print(f'report: {args.report}')
    except OSError as exc:
        subcommand.error(PROG, f'cannot write {exc.filename or "output"}: {exc.strerror or exc}')
        return 1
    return 0


def main(argv: list[str] | None = None) -> int:
    return subcommand.main(PROG, __doc__, configure, run, argv)


if __name__ == '__main__':
    sys.exit(main())
