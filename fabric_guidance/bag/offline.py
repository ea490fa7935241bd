"""Offline replay: pressure_controller's control steps rerun from a bag without DDS.

Every control step the node published its exact inputs (controller_input, layout in
controller_io.py) right before its command, and its parameters, calibration and channel map at
start-up and after a live calibration (controller_parameters). The replay feeds those inputs, in
step order, to the same code the node runs (core/control_step.py guidance_step on a GuidanceController
built by ControllerSetup.make_controller) and compares each step's command with the
pressure_command the node published for it, channel by channel.

Pairing a step with its command does not rely on the order messages of two topics were
received in: controller_input carries the index of its command among all the node's commands;
the offset between that index and the recorded commands (commands published before the
recorder heard the node were not recorded) is the one most steps agree on when each step's
input is paired with the command received nearest to it in time (see pairing_offset).
Steps of a live calibration (Algorithm 1's commands, not Eq. 5's) are not compared.
"""
from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
import time
from typing import Any, Mapping

import numpy as np

from ..core.control_step import StepInput, apply_reset, guidance_step, safe_command
from .controller_io import CONTROLLER_INPUT, CONTROLLER_PARAMETERS, decode_input, setup_from_dict, with_overrides
from ..core.safe_input import excerpt, parse_yaml
from .reader import raw_messages
from .topics import bag_topic
from .writer import typestore

PRESSURE_COMMAND = 'pressure_command'


@dataclass
class Recording:
    """What the offline replay needs from a bag, decoded."""
    setups: list[tuple[int, dict]]        # (from_step, parameters dict), in step order
    inputs: list[StepInput]               # in step order
    commands: list[np.ndarray]            # recorded pressure_command data, in bag order
    offset: int                           # command index - position in `commands`
    read_s: float                         # wall time spent reading and decoding
    problems: list[str] = field(default_factory=list)   # what of the bag could not be read
    recovered: list[str] = field(default_factory=list)  # a cut-off file: what was recovered, what lost


@dataclass
class ReplayResult:
    channels: tuple[str, ...]
    steps: int = 0                        # control steps rerun
    compared: int = 0                     # steps compared with a recorded command
    mismatched: int = 0                   # compared steps whose command differs
    calibrating: int = 0                  # Algorithm 1 steps (not compared)
    unmatched: int = 0                    # steps whose command is not in the bag
    after_last_command: int = 0           # final steps whose command came after the recording stopped
    unsynced: int = 0                     # steps before the controller's state is known (see replay)
    step_gaps: int = 0                    # control steps missing from the bag
    max_diff: np.ndarray = field(default_factory=lambda: np.zeros(0))   # kPa per channel
    worst: dict[str, Any] = field(default_factory=dict)
    bag_duration_s: float = 0.0           # ROS time the steps span
    read_s: float = 0.0
    run_s: float = 0.0
    problems: list[str] = field(default_factory=list)   # the bag's damage: the comparison is partial
    recovered: list[str] = field(default_factory=list)  # cut-off files read up to their last intact chunk

    @property
    def largest(self) -> float:
        return float(self.max_diff.max()) if self.max_diff.size else 0.0

    @property
    def exact(self) -> bool:
        return self.compared > 0 and self.largest == 0.0 and not self.problems

    @property
    def speedup(self) -> float:
        """Bag duration over the replay's wall time, reading and decoding included."""
        total = self.read_s + self.run_s
        return self.bag_duration_s / total if total > 0 else float('inf')


_CDR_LE = b'\x00\x01\x00\x00'


def float64_array(data: bytes) -> np.ndarray | None:
    """The data of a CDR (little endian) std_msgs/Float64MultiArray, read straight from the
    bytes; None for anything else (the caller then decodes it in full). After the 4-byte
    header (offsets and alignment count from its end): the layout's dimensions (a count, then
    each one's label as a length and its bytes, size, stride), data_offset, the data length,
    padding to 8, then the float64s. The package's arrays carry one labelled dimension."""
    end = len(data)
    if end < 16 or data[:4] != _CDR_LE:
        return None

    def uint32(at: int) -> int:
        return int.from_bytes(data[at:at + 4], 'little')

    def align(at: int, n: int) -> int:
        return 4 + (at - 4 + n - 1) // n * n

    dims = uint32(4)
    pos = 8
    if dims > (end - pos) // 12:      # each dimension takes at least 12 bytes: a damaged count
        return None
    for _ in range(dims):
        pos = align(pos, 4)
        pos += 4 + uint32(pos)          # the label: its length (with the NUL), then its bytes
        pos = align(pos, 4) + 8         # size, stride
        if pos > end:
            return None
    pos = align(pos, 4) + 4             # data_offset
    if pos + 4 > end:
        return None
    n = uint32(pos)
    pos = align(pos + 4, 8)
    if end < pos + 8 * n:
        return None
    return np.frombuffer(data, dtype='<f8', count=n, offset=pos)


def load(path, namespace: str = '/') -> Recording:
    """Read a bag's control steps. read_s counts opening, reading and decoding the bag, not
    building rosbags' message types (a one-time start-up cost, like importing the library)."""
    store = typestore()
    t0 = time.perf_counter()
    topics = {bag_topic(CONTROLLER_INPUT, namespace): 'in', bag_topic(CONTROLLER_PARAMETERS, namespace): 'par',
              bag_topic(PRESSURE_COMMAND, namespace): 'cmd'}
    setups, inputs, commands, input_ts, command_ts, problems, recovered = [], [], [], [], [], [], []
    undecodable = Counter()
    for topic, msgtype, stamp, data in raw_messages(path, topics, problems, recovered):
        kind = topics[topic]
        if not 0 <= stamp < 2 ** 63:     # a ROS time is an int64: a damaged timestamp (no chunk CRC)
            undecodable[topic] += 1
            continue
        try:
            if kind == 'par':
                d = parse_yaml(store.deserialize_cdr(data, msgtype).data, f'{topic} message')
                if not isinstance(d, dict):
                    raise ValueError('not a mapping')
                setups.append((int(d.pop('from_step', 0)), d))
                continue
            # The two Float64MultiArray topics are most of the bag: read them without the generic decoder.
            values = float64_array(data)
            if values is None:
                values = np.asarray(store.deserialize_cdr(data, msgtype).data, dtype=float)
            if kind == 'in':
                step = decode_input(values)
        except Exception:  # a damaged message (the CDR decoder raises many kinds): counted, skipped
            undecodable[topic] += 1
            continue
        if kind == 'in':
            inputs.append(step)
            input_ts.append(stamp)
        else:
            commands.append(np.array(values, dtype=float))
            command_ts.append(stamp)
    problems += [f'{n} {t} messages could not be decoded' for t, n in sorted(undecodable.items())]
    damage = f' (the bag is damaged: {"; ".join(problems)})' if problems else ''
    if not setups:
        raise ValueError(f'{path}: no {CONTROLLER_PARAMETERS} (recorded before pressure_controller '
                         f'published it?){damage}')
    if not inputs:
        raise ValueError(f'{path}: no {CONTROLLER_INPUT}: nothing to replay{damage}')
    inputs_by_time = [i.command for i in inputs]
    inputs.sort(key=lambda i: i.step)
    setups.sort(key=lambda s: s[0])
    rec = Recording(setups, inputs, commands, pairing_offset(inputs_by_time, input_ts, command_ts), 0.0,
                    problems, [r.describe() for r in recovered])
    rec.read_s = time.perf_counter() - t0
    return rec


def pairing_offset(input_commands: list[int], input_ts: list[int], command_ts: list[int]) -> int:
    """The offset between a step's command index (controller_input's `command`) and the position
    of that command among the recorded pressure_command messages.

    A step's input and its command are published microseconds apart, steps milliseconds apart;
    the recorder takes them in two subscriptions, so their order in the bag may be either, but
    their receive times are nearest each other. Each step votes for the command received nearest
    in time to its input; a stall of the recorder (a batch received at once) only costs votes.
    Bag order alone cannot tell "input, then its command" from "command, then the next input"."""
    if not command_ts or not input_ts:
        return 0
    ct = np.asarray(command_ts, dtype=np.int64)
    it = np.asarray(input_ts, dtype=np.int64)
    right = np.clip(np.searchsorted(ct, it), 0, len(ct) - 1)
    left = np.clip(right - 1, 0, len(ct) - 1)
    nearest = np.where(np.abs(ct[left] - it) <= np.abs(ct[right] - it), left, right)
    votes = Counter((np.asarray(input_commands, dtype=np.int64) - nearest).tolist())
    return int(votes.most_common(1)[0][0])


def parse_overrides(items) -> dict[str, Any]:
    """['gain=0.1', 'follow_moving_target=true'] -> {'gain': 0.1, ...} (values read as YAML)."""
    out = {}
    for item in items or ():
        key, sep, value = item.partition('=')
        if not sep or not key.strip():
            raise ValueError(f'--set needs NAME=VALUE, got {item!r}')
        out[key.strip()] = parse_yaml(value, f'--set {excerpt(key.strip())}')
    return out


def replay(rec: Recording, overrides: Mapping[str, Any] | None = None) -> ReplayResult:
    """Rerun every recorded control step; compare with the recorded commands."""
    t0 = time.perf_counter()
    try:
        first = setup_from_dict(rec.setups[0][1])
    except (KeyError, TypeError, AttributeError) as exc:  # ValueErrors name their field already
        raise ValueError(f'{CONTROLLER_PARAMETERS}: unusable parameters ({type(exc).__name__}: '
                         f'{excerpt(str(exc))})') from None
    result = ReplayResult(first.channel_map.channels, max_diff=np.zeros(len(first.channel_map.channels)),
                          read_s=rec.read_s, problems=list(rec.problems), recovered=list(rec.recovered))
    setups = [(s, with_overrides(setup_from_dict(d), overrides or {})) for s, d in rec.setups]
    k = -1
    setup = controller = None
    previous_step = None
    # Eq. 5 has state. A bag that starts after the node did (a recorder started mid-session, or
    # discovery still under way) holds steps whose controller state is unknown: the replay
    # compares from the first step where the node's state is known, that is where the node built
    # its controller (start-up, new calibration) or vented it (new target, no gaze, service).
    synced = False
    for inp in rec.inputs:
        while k + 1 < len(setups) and setups[k + 1][0] <= inp.step:
            k += 1
            setup = setups[k][1]
            controller = setup.make_controller()     # as the node builds it (start-up, new calibration)
            synced = synced or setups[k][0] == inp.step
        if setup is None:                            # steps before the first parameters: none expected
            continue
        if previous_step is not None and inp.step != previous_step + 1:
            result.step_gaps += inp.step - previous_step - 1
            synced = False                           # the missing steps changed the state
        previous_step = inp.step
        result.steps += 1
        if inp.reset:
            synced = True
            apply_reset(controller, inp)
        if inp.calibrating:
            result.calibrating += 1
            continue
        channels, reason, _ = guidance_step(setup, controller, inp)
        command = safe_command(channels, setup.p_max_kpa)
        if not synced and not reason:
            result.unsynced += 1
            continue
        synced = True                                # a vented step is known; so is every one after it
        position = inp.command - rec.offset
        if position >= len(rec.commands):
            # The recorder stopped between this step's input and its command (both are published
            # at the end of the step): the end of the recording, not a lost message.
            result.after_last_command += 1
            continue
        if position < 0 or len(rec.commands[position]) != len(command):
            result.unmatched += 1
            continue
        result.compared += 1
        diff = np.abs(command - rec.commands[position])
        result.mismatched += bool(diff.any())
        worst = int(np.argmax(diff))
        if diff[worst] > result.max_diff.max() or not result.worst:
            result.worst = dict(step=inp.step, t=inp.t, channel=result.channels[worst],
                                recorded=float(rec.commands[position][worst]), replayed=float(command[worst]),
                                diff=float(diff[worst]))
        result.max_diff = np.maximum(result.max_diff, diff)
    result.run_s = time.perf_counter() - t0
    ts = [i.t for i in rec.inputs]
    result.bag_duration_s = (max(ts) - min(ts)) if ts else 0.0
    return result


def report(result: ReplayResult, overrides: Mapping[str, Any] | None, say) -> None:
    changed = ', '.join(f'{k}={v}' for k, v in (overrides or {}).items()) or 'none (the recorded parameters)'
    for line in result.recovered:
        say(line)
    say(f'offline replay: {result.steps} control steps rerun, {result.compared} compared with the recorded '
        f'pressure_command; parameters changed: {changed}')
    if result.calibrating or result.unmatched or result.step_gaps or result.unsynced or result.after_last_command:
        say(f'  not compared: {result.calibrating} calibration steps, {result.unmatched} steps whose command is not '
            f'in the bag, {result.after_last_command} after the last recorded command, {result.unsynced} steps '
            'before the controller\'s state is known (the bag starts '
            f'mid-guidance; compared from the first vent); {result.step_gaps} control steps missing from the bag')
    say(f'  {"channel":<8} {"max |diff| kPa":>14}')
    for name, d in zip(result.channels, result.max_diff):
        say(f'  {name:<8} {d:14.6g}')
    for problem in result.problems:
        say(f'  UNREADABLE: {problem}')
    if result.problems:
        say('  the bag is damaged: the comparison covers only what could be read, so it is not called '
            'exact')
    if result.largest == 0.0:
        say('  largest difference: 0 kPa: every compared command reproduced exactly (bit for bit)'
            + (' (of the readable part only)' if result.problems else
               ' (of the recovered part)' if result.recovered else ''))
    else:
        w = result.worst
        say(f"  largest difference: {w['diff']:.6g} kPa on {w['channel']} at step {w['step']} (t = {w['t']:.3f} s): "
            f"recorded {w['recorded']:.6g}, replayed {w['replayed']:.6g}")
    say(f'  {result.bag_duration_s:.2f} s of session in {result.read_s + result.run_s:.3f} s '
        f'(reading {result.read_s:.3f} s, controller {result.run_s:.3f} s): {result.speedup:.0f}x real time')
