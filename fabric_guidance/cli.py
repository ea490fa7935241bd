"""fabric-guidance: the package's command line.

  demo      the simulated ROS graph, a guided session, what happened (`make demo`)
  replay    a recorded session: through the graph with /clock, or --offline against the controller
  calibration-report  a calibration file's fit per direction, as text and a PNG
  analyze   the paper's statistics (Friedman, Dunn-Bonferroni) on a subjects x conditions table
  experiment  one of the paper's experiments on simulated wearers, with statistics, plots, report
  tradeoff  what accuracy costs in time: every knob swept, table, plots and a reading
  fit-wearer  fit the simulated wearer's human parameters to the paper's speed means
  compare-paper  both experiments on several seeds, every figure of the paper beside the model's
  sensitivity  which headline figures rest on which assumed human parameters (low/high sweep)
  beyond    the Discussion's two open points in simulation: per-wearer gain, moving targets
  bench     benchmarks: gaze-to-regulator latency against the transports' floor, costs, speed
  example   the core alone on a worked example (no ROS)
"""
from __future__ import annotations

import argparse
from pathlib import Path
import sys
import tempfile

from .core import (DIRECTIONS, PAPER_GAIN, PAPER_P_MAX, ChannelMap, GuidanceController, PowerLaw,
                   condition, phrase)
from .paths import config_path
from .sim.headless import calibrate, guide, within
from .sim.wearer import SimulatedWearer

#: The demo wearer's own sensitivity per direction (left, right, down, up): what Algorithm 1
#: has to discover. Bending needs more pressure per degree than twisting; every target of the
#: paper's range (60 deg horizontal, 30 deg vertical) is reachable below 375 kPa.
DEMO_WEARER = (PowerLaw(20.0, 0.65, 25.0), PowerLaw(22.0, 0.62, 20.0),
               PowerLaw(40.0, 0.55, 30.0), PowerLaw(38.0, 0.58, 35.0))
#: Targets of the guided session: (horizontal, vertical) degrees from the front, positive left/up.
DEMO_TARGETS = ((40.0, 0.0), (-36.0, 12.0), (25.0, -20.0), (-50.0, -10.0))


def _fmt_law(law: PowerLaw) -> str:
    return f'{law.a:7.2f} {law.b:5.3f} {law.c:6.2f}'


def run_worked_example(out_dir: Path, stream=sys.stdout) -> int:
    def say(line: str = '') -> None:
        print(line, file=stream, flush=True)

    say('fabric_guidance worked example: the core on a simulated wearer (no ROS graph)')
    say()
    wearer = SimulatedWearer(DEMO_WEARER, tau_s=0.4)
    say(f'1. Calibration (Algorithm 1): 10 pressure steps per direction up to {PAPER_P_MAX:g} kPa, '
        'Levenberg-Marquardt fit of P = a*theta^b + c')
    cal = calibrate(wearer, 'demo-wearer', dwell_s=2.0, rest_s=2.0, record_window_s=0.3)
    say(f'   {"direction":<9} {"true a     b      c":<22} {"fitted a   b      c":<22} {"RMSE kPa":>8} '
        f'{"R^2":>7} {"max|dP| 0-60deg":>15}')
    for d, true_law in zip(DIRECTIONS, DEMO_WEARER):
        fit = cal.directions[d]
        say(f'   {d:<9} {_fmt_law(true_law):<22} {_fmt_law(fit.law):<22} {fit.fit["rmse_kpa"]:8.3f} '
            f'{fit.fit["r2"]:7.4f} {within(true_law, fit.law):12.2f} kPa')
    path = cal.save(out_dir / 'demo-wearer.yaml')
    say(f'   calibration file: {path}')
    say()
    cond = condition(1)
    cmap = ChannelMap.load(config_path('hardware/channel_map.yaml'))
    controller = GuidanceController(cal.laws, p_max=cal.p_max, gain=PAPER_GAIN, mode=cond.mode)
    say(f'2. Guided session, condition {cond.number} ({cond.name}), G = {PAPER_GAIN}, 50 Hz, '
        'found within 5 deg for 0.3 s')
    say(f'   {"target h, v deg":<16} {"condition 4 would say":<30} {"found":<5} {"time s":>6} '
        f'{"error deg":>9}  peak kPa ' + ' '.join(f'{d:>5}' for d in DIRECTIONS))
    results = guide(wearer, controller, DEMO_TARGETS, channel_map=cmap, layout=cond.layout)
    for r in results:
        say(f'   {r.horizontal_deg:6.1f}, {r.vertical_deg:6.1f}   {phrase(r.horizontal_deg, r.vertical_deg):<30} '
            f'{"yes" if r.found else "no":<5} {r.time_s:6.2f} {r.final_error_deg:9.2f}           '
            + ' '.join(f'{r.peak_kpa[d]:5.0f}' for d in DIRECTIONS))
    found = sum(r.found for r in results)
    peak = max(max(r.peak_kpa.values()) for r in results)
    say()
    say(f'{found} of {len(results)} targets found; highest pressure commanded {peak:.1f} kPa '
        f'(limit {PAPER_P_MAX:g} kPa).')
    return 0 if found == len(results) else 1


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog='fabric-guidance', description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest='command', required=True)
    demo = sub.add_parser('demo', help='run the simulated ROS graph for a short guided session and report it')
    demo.add_argument('--condition', type=int, default=None, choices=(1, 2, 3, 4),
                      help='guidance condition (1 surface adjusted, 2 surface fixed, 3 arm adjusted; '
                           '4 speech, with --scene only); default 1, or the scene\'s first')
    demo.add_argument('--scene', default=None,
                      help='run a scene of the simulator (config/scenes name or file) through the graph')
    demo.add_argument('--timeout', type=float, default=45.0, help='give up after this many seconds')
    demo.add_argument('--out', type=Path, default=None, help='folder for logs (default: a temporary folder)')
    demo.add_argument('--record', type=Path, default=None, metavar='DIR',
                      help='record the session as a ROS 2 bag (MCAP) in DIR')
    from . import calibration_report, replay
    from .bench import runner as bench
    from .experiments import (analyze, beyond, experiment, fit_wearer, paper_comparison, sensitivity,
                              tradeoff)
    for module in (replay, calibration_report, analyze, experiment, fit_wearer, tradeoff,
                   paper_comparison, sensitivity, beyond, bench):
        module.add_parser(sub).set_defaults(run=module.run)
    example = sub.add_parser('example', help='the core alone on a worked example: calibration and guided turns')
    example.add_argument('--out', type=Path, default=None,
                         help='folder for the calibration file (default: a temporary folder)')
    args = parser.parse_args(argv)
    if args.command == 'demo':
        from .demo import run_demo  # imports rclpy: only for the graph
        return run_demo(args.condition, args.timeout, args.out, scene=args.scene, record_dir=args.record)
    if args.command != 'example':
        return args.run(args)
    if args.out is not None:
        return run_worked_example(args.out)
    with tempfile.TemporaryDirectory(prefix='fabric-guidance-example-') as tmp:
        return run_worked_example(Path(tmp))


if __name__ == '__main__':
    sys.exit(main())
