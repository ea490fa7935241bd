"""`fabric-guidance study`: the paper's study session, through the graph.

  fabric-guidance study --simulated --participants 5 --protocol speed --out DIR

runs the session on the simulated graph with a scene's wearers as participants (wearer_sim
presses the key as the headless model does); --trials and --trial-s shorten it, --seed changes
the scene's seed (the population, the targets, the condition orders). The scene used is written
to DIR/scene-<protocol>.yaml, so that `fabric-guidance experiment --scene DIR/scene-speed.yaml`
runs the same study headless; both tasks may share one study folder (a BIDS dataset). The
session is study.session's state machine driven on the graph (driver.py); every finished trial is
in the study folder (study.store) at once, atomically; run the same command again on the same DIR
after a crash and the session resumes at the first unfinished block (the graph's nodes end with
the command, however it ends). `fabric-guidance analyze DIR` analyses it.

  fabric-guidance study --participant P07 --protocol speed --out DIR [--namespace NS]

runs a participant's session on the graph that is running (ros2 launch ... study:=speed):
registered in DIR, calibrated from the graph if pressure_controller has no calibration of theirs,
then their blocks (live_session.py). The operator's keys: space/Enter confirm, p pause,
c resume, r repeat, s skip, q stop (vents at once). Run it again after a crash: it resumes.

--press-source SOURCES (a comma list of keyboard, headset, wearer_sim, ros; default all) names
the confirm sources the session judges: a press from another source is not judged, is counted in
its trial's ignored_presses and reported once per trial. The simulated participant presses
through the headset's uplink: its source is headset.

`fabric-guidance study --keyboard` makes the operator's terminal the confirm source of a running
graph: space or Enter publishes `confirm` (frame_id 'keyboard', stamped when the key is read);
q ends (live_study/keyboard.py also reads p pause, r repeat, s skip, c resume for a session).
"""
from __future__ import annotations

import argparse
from pathlib import Path
import sys

import yaml

from .. import subcommand
from ..atomic import write_text
from ..study.plan import PRESS_SOURCES, parse_press_sources

PROG = 'fabric-guidance study'
#: The line after Ctrl-C (subcommand.interrupted): the session's `finally` blocks have closed its
#: trial gate (--participant) or stopped its simulated graph (--simulated) and closed its files.
ON_STOP = 'the session is stopped; the trials that ended are in the study folder, and the same command resumes it'

HELP = "run the paper's study session through the graph (--simulated: a scene's wearers as participants)"
SCENES = {'speed': 'paper-speed', 'accuracy': 'paper-accuracy'}


def configure(p: argparse.ArgumentParser) -> argparse.ArgumentParser:
    p.add_argument('--simulated', action='store_true', help="the simulated graph, the scene's wearers as participants")
    p.add_argument('--participants', type=int, default=5, help='simulated participants (the first N wearers)')
    p.add_argument('--participant', default=None,
                   help='a live session with this participant (1-64 letters or digits) on the running graph')
    p.add_argument('--session', type=int, default=1, help='the session number of a live session (BIDS ses-<n>)')
    p.add_argument('--namespace', default='', help="the running graph's namespace (launch's namespace:=)")
    p.add_argument('--no-keys', action='store_true',
                   help="a live session without the operator's keys (confirm from the headset or a ROS tool)")
    p.add_argument('--protocol', choices=sorted(SCENES), default='speed')
    p.add_argument('--scene', default=None, help='a scene file or name (default: paper-speed / paper-accuracy)')
    p.add_argument('--keyboard', action='store_true',
                   help="only the operator's key as the confirm source on the running graph (ROS_DOMAIN_ID "
                        'from the environment): space or Enter publishes confirm, q ends')
    p.add_argument('--out', type=Path, default=None, help='the study folder (required with --simulated)')
    p.add_argument('--trials', type=int, default=None, help='trials per condition (default: the scene\'s)')
    p.add_argument('--trial-s', type=float, default=None, help='seconds per speed trial (default: the scene\'s, 40)')
    p.add_argument('--seed', type=int, default=None, help="the scene's seed (default: the scene's)")
    p.add_argument('--latin-square', action='store_true', help='condition orders from a Latin square')
    p.add_argument('--press-source', default='all', metavar='SOURCES',
                   help='the confirm sources the session judges, a comma list of ' + ', '.join(PRESS_SOURCES) +
                        " (a confirm's frame_id; ros: any other sender), or all (default); a press from another "
                        'source is counted and ignored')
    return p


def add_parser(subparsers) -> argparse.ArgumentParser:
    return subcommand.add(subparsers, 'study', HELP, __doc__, configure, run)


#: The scene fields the options set: an error in one of them names the option.
OPTION_FIELDS = {'seed': '--seed', 'repetitions': '--trials', 'protocol.trial_s': '--trial-s'}


def study_scene_data(args) -> dict:
    """The scene of the study's task with --seed/--trials/--trial-s applied, checked (an error
    in a field an option set names the option), before anything is written."""
    from ..sim.scene import SceneError, scene_from_dict, scene_path
    source = scene_path(args.scene or SCENES[args.protocol])
    data = yaml.safe_load(Path(source).read_text())
    if args.seed is not None:
        data['seed'] = int(args.seed)
    if args.trials is not None:
        data['repetitions'] = int(args.trials)
    if args.trial_s is not None:
        if data['protocol'].get('kind') != 'speed':
            raise ValueError('--trial-s: only the speed protocol has timed trials')
        data['protocol']['trial_s'] = float(args.trial_s)
    try:
        scene = scene_from_dict(data, source=str(source))
    except SceneError as exc:
        option = OPTION_FIELDS.get(exc.field)
        if option and getattr(args, option[2:].replace('-', '_')) is not None:
            raise ValueError(f'{option}: {exc.reason}') from None
        raise
    if scene.protocol.kind != args.protocol:
        raise ValueError(f'--scene: {scene.name} is a {scene.protocol.kind} scene, not {args.protocol}')
    if args.simulated and not 1 <= args.participants <= scene.population.subjects:
        raise ValueError(f'--participants: 1..{scene.population.subjects} (the scene\'s wearers), '
                         f'got {args.participants}')
    if args.simulated and args.latin_square and len(scene.conditions) % 2:
        raise ValueError(f'--latin-square: a balanced Latin square needs an even number of conditions, '
                         f'the scene has {len(scene.conditions)}')
    return data


def study_scene(args, out: Path, data: dict | None = None):
    """The scene of study_scene_data(args), written to out/scene-<protocol>.yaml (wearer_sim
    reads the scene from that file; one per task, so that one study folder holds both tasks)
    and loaded from there."""
    from ..sim.scene import load_scene
    data = study_scene_data(args) if data is None else data
    written = out / f'scene-{args.protocol}.yaml'
    existing = written.read_text() if written.exists() else None
    text = yaml.safe_dump(data, sort_keys=False)
    if existing is not None and yaml.safe_load(existing) != data:
        raise ValueError(f'{written}: this study folder was started with another scene or other options; '
                         'use a new --out or the same options')
    write_text(written, text)
    return load_scene(written)


def run(args: argparse.Namespace) -> int:
    say = subcommand.printer(sys.stdout)
    if args.keyboard:
        return keyboard_only(say)
    if args.out is None:
        subcommand.error(PROG, '--out DIR: the study folder is required')
        return 2
    if args.simulated == (args.participant is not None):
        subcommand.error(PROG, 'either --simulated (a scene\'s wearers) or --participant ID (a person on the '
                         'running graph)')
        return 2
    try:
        args.press_sources = parse_press_sources(args.press_source)
    except ValueError as exc:
        subcommand.error(PROG, f'--press-source: {exc}')
        return 2
    out = args.out.expanduser().resolve()
    if not args.simulated:
        return run_live(args, out, say)
    from ..study.store import Study, StudyError
    try:
        data = study_scene_data(args)   # every option checked before the folder is made
        Study.open(out)     # a new folder, or a study folder to resume; refused otherwise
        scene = study_scene(args, out, data)
    except (StudyError, ValueError, OSError) as exc:
        subcommand.error(PROG, exc)
        return 2
    from .session_graph import run_study_session
    if args.press_sources and 'headset' not in args.press_sources:
        say(f"--press-source {','.join(args.press_sources)}: the simulated participants press through the headset's "
            'uplink (source headset), so none of their presses is judged')
    try:
        return run_study_session(scene, args.participants, out, say, 'latin' if args.latin_square else 'random',
                                 args.press_sources)
    except (StudyError, OSError) as exc:     # DiskFull is an OSError: what was recorded is intact
        subcommand.error(PROG, exc)
        return 1


def run_live(args, out: Path, say) -> int:
    """A live session with a person on the running graph (live_session.py)."""
    from ..study.plan import check_participant
    from ..study.store import Study, StudyError
    from .live_session import LiveStudyError, run_live_session
    try:
        check_participant(args.participant)
        if args.session < 1:
            raise ValueError(f'--session: 1 or more, got {args.session}')
        data = study_scene_data(args)   # every option checked before the folder is made
        Study.open(out)
        scene = study_scene(args, out, data)
    except (StudyError, ValueError, OSError) as exc:
        subcommand.error(PROG, exc)
        return 2
    try:
        return run_live_session(scene, args.participant, args.session, out, say,
                                'latin' if args.latin_square else 'random', args.namespace, not args.no_keys,
                                press_sources=args.press_sources)
    except (LiveStudyError, StudyError, OSError) as exc:
        subcommand.error(PROG, exc)
        return 1


def keyboard_only(say) -> int:
    """The operator's key as confirm on the running graph until q (or end of input)."""
    from .keyboard import KeyboardSource
    from .operator import Operator
    op = Operator(name='study_keyboard')
    try:
        say('keyboard: space or Enter presses confirm (frame_id keyboard); q ends')

        def press():
            op.press_key('keyboard')
            say(f'confirm at {op.now_ns() * 1e-9:.3f} s')
        src = KeyboardSource(press).start()
        src.join()
    finally:
        op.close()
    return 0


def main(argv=None) -> int:
    return subcommand.main(PROG, __doc__, configure, run, argv)


if __name__ == '__main__':
    sys.exit(main())
