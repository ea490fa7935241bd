"""`fabric-guidance example`: the core alone on a worked example (no ROS graph).

A simulated wearer of known sensitivity is calibrated (Algorithm 1) and then guided to four
targets under condition 1; the fitted laws are printed beside the true ones, and each target's
time, final error and peak pressures beside what condition 4 would have said.
"""
from __future__ import annotations

import argparse
from pathlib import Path
import sys
import tempfile

from .. import subcommand
from ..core import (DIRECTIONS, PAPER_GAIN, PAPER_P_MAX, ChannelMap, GuidanceController, PowerLaw,
                    condition, phrase)
from ..paths import config_path
from ..sim.worked_example import calibrate, guide, within
from ..sim.wearer import SimulatedWearer

PROG = 'fabric-guidance example'
HELP = 'the core alone on a worked example: calibration and guided turns'

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
    say = subcommand.printer(stream)

    say('fabric_guidance worked example: the core on a simulated wearer (no ROS graph)')
    say()
    wearer = SimulatedWearer(DEMO_WEARER, tau_s=0.4)
    say('1. Calibration (Algorithm 1): 10 pressure steps per direction up to '
        f'{PAPER_P_MAX:g} kPa, least-squares fit of P = a*theta^b + c')
    cal = calibrate(wearer, 'demo-wearer', dwell_s=2.0, rest_s=2.0, record_window_s=0.3)
    say(f'   {"direction":<9} {"true a     b      c":<22} {"fitted a   b      c":<22} '
        f'{"RMSE kPa":>8} {"R^2":>7} {"max|dP| 0-60deg":>15}')
    for d, true_law in zip(DIRECTIONS, DEMO_WEARER):
        fit = cal.directions[d]
        say(f'   {d:<9} {_fmt_law(true_law):<22} {_fmt_law(fit.law):<22} '
            f'{fit.fit["rmse_kpa"]:8.3f} {fit.fit["r2"]:7.4f} '
            f'{within(true_law, fit.law):12.2f} kPa')
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
        spoken = phrase(r.horizontal_deg, r.vertical_deg)
        say(f'   {r.horizontal_deg:6.1f}, {r.vertical_deg:6.1f}   {spoken:<30} '
            f'{"yes" if r.found else "no":<5} {r.time_s:6.2f} {r.final_error_deg:9.2f}           '
            + ' '.join(f'{r.peak_kpa[d]:5.0f}' for d in DIRECTIONS))
    found = sum(r.found for r in results)
    peak = max(max(r.peak_kpa.values()) for r in results)
    say()
    say(f'{found} of {len(results)} targets found; highest pressure commanded {peak:.1f} kPa '
        f'(limit {PAPER_P_MAX:g} kPa).')
    return 0 if found == len(results) else 1


def configure(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    parser.add_argument('--out', type=Path, default=None,
                        help='folder for the calibration file (default: a temporary folder)')
    return parser


def add_parser(subparsers) -> argparse.ArgumentParser:
    return subcommand.add(subparsers, 'example', HELP, __doc__, configure, run)


def run(args: argparse.Namespace) -> int:
    if args.out is not None:
        return run_worked_example(args.out)
    with tempfile.TemporaryDirectory(prefix='fabric-guidance-example-') as tmp:
        return run_worked_example(Path(tmp))


def main(argv: list[str] | None = None) -> int:
    return subcommand.main(PROG, __doc__, configure, run, argv)


if __name__ == '__main__':
    sys.exit(main())
