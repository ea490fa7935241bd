"""fabric-guidance: the package's command line.

  demo      the simulated ROS graph, a guided session, what happened (`make demo`)
  dry-run   the lab graph against a mock PLC on this PC, the real headset, no suit (a lab's dry run)
  replay    a recorded session: through the graph with /clock, or --offline against the controller
  recover   a complete bag (summary, metadata.yaml) from the intact part of a cut-off recording
  calibration-report  a calibration file's fit per direction, as text and a PNG
  analyze   the paper's statistics (Friedman, Dunn-Bonferroni) on a subjects x conditions table
  study     the paper's study session through the graph, trial rows in a study folder
  experiment  one of the paper's experiments on simulated wearers, with statistics, plots, report
  tradeoff  what accuracy costs in time: every knob swept, table, plots and a reading
  fit-wearer  fit the simulated population to the paper's whole speed table across seeds
  compare-paper  both experiments on several seeds, every figure of the paper beside the model's
  sensitivity  which headline figures rest on which assumed human parameters (low/high sweep)
  beyond    the Discussion's two open points in simulation: per-wearer gain, moving targets
  bench     benchmarks: gaze-to-regulator latency against the transports' floor, costs, speed
  chaos     a seeded schedule of faults on the lab graph, invariants checked from the PLC's log
  soak      the simulated graph guiding for N minutes: figures per minute and a verdict on drift
  example   the core alone on a worked example (no ROS)
  dds-profile  a Fast DDS profile keeping DDS on one network interface of the lab PC
  discovery-server  Fast DDS's discovery server for the lab graph (no multicast discovery)
  security-policy  the SROS2 permissions policy of the lab graph, from the interface table
"""
from __future__ import annotations

import argparse
from importlib import import_module
import sys

from .. import subcommand

#: Every subcommand: its module (which has add_parser(subparsers) and run(args)) and the one line
#: `fabric-guidance --help` lists. A module is imported only when its subcommand runs, so each
#: pays only for its own dependencies (bench needs no scikit-posthocs, example no pandas).
SUBCOMMANDS = {
    'demo': ('fabric_guidance.commands.demo_command',
             'run the simulated ROS graph for a short guided session and report it'),
    'dry-run': ('fabric_guidance.commands.dry_run', 'run the lab graph against a mock PLC on this PC, with the '
                'real headset and no suit (a dry run)'),
    'replay': ('fabric_guidance.commands.replay', 'replay a recorded session: offline through the '
               'controller, or republished with /clock for the graph'),
    'recover': ('fabric_guidance.commands.recover', 'write a complete bag (summary, metadata.yaml) from the intact '
                'part of a cut-off recording'),
    'calibration-report': ('fabric_guidance.lab.calibration_report',
                           "write the fit report (text and PNG) of a wearer's calibration file"),
    'analyze': ('fabric_guidance.experiments.analyze', 'Friedman test + Dunn-Bonferroni post-hoc '
                "on a subjects x conditions CSV (as the paper's table) or on a live study's folder"),
    'study': ('fabric_guidance.live_study.study_command', "run the paper's study session through the graph "
              "(--simulated: a scene's wearers as participants)"),
    'experiment': ('fabric_guidance.experiments.experiment',
                   "run one of the paper's experiments on simulated wearers"),
    'fit-wearer': ('fabric_guidance.experiments.fit_wearer',
                   "fit the simulated population to the paper's whole speed table across seeds"),
    'tradeoff': ('fabric_guidance.experiments.tradeoff',
                 'sweep the knobs that buy accuracy with time; table, plots and a reading of the '
                 'curves'),
    'compare-paper': ('fabric_guidance.experiments.paper_comparison', 'run both protocols on '
                      "several seeds and set every figure of the paper beside the simulation's"),
    'sensitivity': ('fabric_guidance.experiments.sensitivity', 'vary every assumed human '
                    'parameter low and high: how much each moves the headline figures'),
    'beyond': ('fabric_guidance.experiments.discussion.beyond', 'beyond the paper, in simulation: a '
               "per-wearer gain G and moving targets, with the paper's statistics"),
    'bench': ('fabric_guidance.bench.runner', "benchmarks: gaze to regulator latency against the "
              "transports' floor, component costs, memory, simulation and replay speed"),
    'chaos': ('fabric_guidance.bench.chaos', 'a seeded schedule of faults on the lab graph, invariants '
              'checked from the PLC register log'),
    'soak': ('fabric_guidance.bench.soak', 'the simulated lab graph guiding target after target for N minutes: '
             'latency, resources and losses per minute, a verdict on drift'),
    'example': ('fabric_guidance.commands.example_command',
                'the core alone on a worked example: calibration and guided turns'),
    'dds-profile': ('fabric_guidance.lab.lab_network', 'write (or check) a Fast DDS profile that keeps DDS on one '
                    'network interface of the lab PC'),
    'discovery-server': ('fabric_guidance.lab.discovery_server',
                         "run Fast DDS's discovery server for the lab graph (no multicast discovery)"),
    'security-policy': ('fabric_guidance.lab.security_policy', 'write the SROS2 permissions policy of the lab graph, '
                        'generated from the interface table'),
}


def _command(argv: list[str]) -> str | None:
    """The subcommand argv names (its first word; the top parser has no option but -h)."""
    return argv[0] if argv and argv[0] in SUBCOMMANDS else None


#: How to install a Python module a command needs, where rosdep does not (package.xml).
NOT_IN_ROSDEP = {'scikit_posthocs': 'pip install scikit-posthocs (it has no rosdep key)',
                 'distributed': 'pip install distributed (it has no rosdep key)'}


def main(argv: list[str] | None = None) -> int:
    """The command; a Python module it needs and does not find: one line naming it, and 2."""
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        return _main(argv)
    except ModuleNotFoundError as exc:
        if not exc.name or exc.name.split('.')[0] == 'fabric_guidance':
            raise
        how = NOT_IN_ROSDEP.get(exc.name.split('.')[0], 'rosdep install --from-paths src --ignore-src -y '
                                '(package.xml declares it)')
        command = ' '.join(['fabric-guidance', *argv[:1]])
        print(f'{command}: error: the Python module {exc.name} is not installed: {how}', file=sys.stderr)
        return 2


def _main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog='fabric-guidance', description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest='command', required=True)
    chosen = _command(argv)
    chosen_parser = parser
    for name, (module, help_text) in SUBCOMMANDS.items():
        if name == chosen:
            chosen_module = import_module(module)
            chosen_parser = chosen_module.add_parser(sub)
            # set here too: not every module's add_parser sets run itself
            chosen_parser.set_defaults(run=chosen_module.run)
        else:  # listed, not imported: its options are parsed only when it is the one chosen
            sub.add_parser(name, help=help_text)
    args, unknown = parser.parse_known_args(argv)
    if unknown:   # a mistyped option of a subcommand: that subcommand's usage, not the top one's
        chosen_parser.error(f'unrecognized arguments: {" ".join(unknown)}')
    subcommand.stop_on_sigterm()
    return subcommand.run_until_stopped(f'fabric-guidance {args.command}', args.run, args)


if __name__ == '__main__':
    sys.exit(main())
