"""A scripted participant wearing the compiled C# headset (headset_harness.Harness, started with
`--commands stdin`): it reads the harness's log as it grows, and on each new target the display
shows it takes a moment to find it, turns its eyes to it from the eye (docs/headset.md: Unity
(0, eye_height, 0)) in a few steps, as a person turns, waits until the harness has sent frames
of the settled gaze, and presses confirm; when the target goes (found, or its trial over) it
looks back straight ahead. It only knows what a headset knows: the display messages, and what
it did itself, which it records (Seen, Pressed) for a test to hold the session's records against.

    person = HeadsetParticipant(harness, eye_height_m=1.2)
    person.start()
    ...                                  # the session runs
    person.stop()                        # then the harness's, then person.read_log()
    person.seen, person.presses, person.events('found')
"""
from __future__ import annotations

from dataclasses import dataclass
import json
import math
import random
import threading
import time

#: Straight ahead from the eye, Unity world (z forward).
FRONT = (0.0, 0.0, 1.0)


def unit(v) -> tuple[float, float, float]:
    n = math.sqrt(sum(c * c for c in v))
    return tuple(c / n for c in v)


def direction_to(position, eye) -> tuple[float, float, float]:
    """The unit direction from the eye to a position (Unity world)."""
    return unit([p - e for p, e in zip(position, eye)])


def yaw_pitch_deg(direction) -> tuple[float, float]:
    """A Unity direction as the session's angles: azimuth positive left (REP 103), elevation up."""
    x, y, z = direction
    return math.degrees(math.atan2(-x, z)), math.degrees(math.atan2(y, math.hypot(x, z)))


def turned_left(direction, deg: float) -> tuple[float, float, float]:
    """The direction turned `deg` to the left about the vertical (Unity y up, x right)."""
    a = math.radians(deg)
    x, y, z = direction
    return (x * math.cos(a) - z * math.sin(a), y, x * math.sin(a) + z * math.cos(a))


@dataclass
class Seen:
    """A target as the display showed it: its Unity position, the harness's receive time
    (headset clock) of the first targets message that showed it there, and the PC's send stamp."""
    position: tuple
    t: float
    stamp: float


@dataclass
class Pressed:
    """A confirm the participant pressed: the target it looked at, the direction it looked, when
    it sent the command (time.monotonic()), and the harness's log of the press (press_id, headset
    clock stamp) once read."""
    target: Seen
    direction: tuple
    sent_s: float
    press_id: int | None = None
    stamp: float | None = None


class HeadsetParticipant:
    """See the module docstring. reaction_s: (shortest, longest) time to find a target among the
    dummies before turning to it, drawn uniformly (seeded); miss_deg: look that far to the left of
    every target (a test of the test); steps: the turn's steps; step_frames, settle_frames: frames
    the harness must have sent after a step, and after the last one before the press."""

    def __init__(self, harness, eye_height_m: float = 1.2, reaction_s: tuple[float, float] = (0.3, 1.2),
                 miss_deg: float = 0.0, steps: int = 3, step_frames: int = 3, settle_frames: int = 10,
                 seed: int = 1, poll_s: float = 0.005):
        self.harness = harness
        self.eye = (0.0, float(eye_height_m), 0.0)
        self.reaction_s, self.rng = reaction_s, random.Random(seed)
        self.miss_deg, self.steps = float(miss_deg), int(steps)
        self.step_frames, self.settle_frames, self.poll_s = int(step_frames), int(settle_frames), poll_s
        self.seen: list[Seen] = []
        self.presses: list[Pressed] = []
        self.looks: list[tuple[float, tuple]] = []    # (time.monotonic() sent, direction)
        self.entries: list[dict] = []                  # the harness log, as read so far
        self.errors: list[BaseException] = []
        self._offset = 0
        self._partial = ''
        self._shown: tuple | None = None        # (active, position) of the last targets message
        self._version = 0                       # counts the changes of _shown
        self._frames_since_look = 0             # frames the harness sent since the last look it logged
        self._looks_logged = 0
        self._confirms: list[dict] = []
        self._looking = FRONT
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name='headset-participant', daemon=True)

    # ---- the harness's log
    def _pump(self) -> None:
        with open(self.harness.log_path, encoding='utf-8') as f:
            f.seek(self._offset)
            text = f.read()
            self._offset = f.tell()
        lines = (self._partial + text).split('\n')
        self._partial = lines.pop()      # a line still being written
        for line in lines:
            if not line.strip():
                continue
            entry = json.loads(line)
            self.entries.append(entry)
            if 'sent' in entry:
                self._frames_since_look += 1
            elif 'look' in entry:
                self._frames_since_look = 0
                self._looks_logged += 1
            elif 'confirm' in entry:
                self._confirms.append(entry)
            elif entry.get('msg', {}).get('kind') == 'targets':
                self._on_targets(entry)

    def _on_targets(self, entry: dict) -> None:
        msg = entry['msg']
        position = next((tuple(t['position']) for t in msg['targets'] if t['id'] == msg['active']), None)
        shown = (msg['active'], position) if msg['active'] and position is not None else None
        if shown != self._shown:
            self._shown = shown
            self._version += 1
            if shown is not None:
                self.seen.append(Seen(position, entry['t'], msg['stamp']))

    def _wait(self, predicate, timeout_s: float | None = None) -> bool:
        """Pump the log until predicate() (True) or the stop or timeout_s (False)."""
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        while not self._stop.is_set():
            self._pump()
            if predicate():
                return True
            if deadline is not None and time.monotonic() > deadline:
                return False
            time.sleep(self.poll_s)
        return False

    # ---- what the person does
    def _look(self, direction) -> None:
        self.harness.command('look {:.9f} {:.9f} {:.9f}'.format(*direction))
        self.looks.append((time.monotonic(), tuple(direction)))
        self._looking = tuple(direction)
        count = len(self.looks)
        # frames count from the harness's own line for this look: the ones after it carry it
        if not self._wait(lambda: self._looks_logged >= count, 10.0) and not self._stop.is_set():
            raise AssertionError(f'the harness did not log the look {direction} within 10 s')

    def _turn_to(self, goal, version: int) -> bool:
        """Turn the eyes to `goal` in steps (each one sent in step_frames frames), then hold it
        for settle_frames; False when the display changed meanwhile."""
        start = self._looking
        for k in range(1, self.steps + 1):
            f = k / self.steps
            self._look(unit([a + (b - a) * f for a, b in zip(start, goal)]))
            frames = self.settle_frames if k == self.steps else self.step_frames
            if not self._wait(lambda: self._frames_since_look >= frames or self._version != version, 10.0):
                return False
            if self._version != version:
                return False
        return True

    def _press(self, target: Seen, direction) -> None:
        pressed = Pressed(target, tuple(direction), time.monotonic())
        self.harness.command('confirm')
        self.presses.append(pressed)
        count = len(self.presses)
        if self._wait(lambda: len(self._confirms) >= count, 10.0):
            confirm = self._confirms[count - 1]
            pressed.press_id, pressed.stamp = confirm['confirm'], confirm['stamp']

    def _run(self) -> None:
        try:
            while not self._stop.is_set():
                if not self._wait(lambda: self._shown is not None):
                    return
                version, target = self._version, self.seen[-1]
                # the search among the dummies: the display watched meanwhile, not slept through
                if self._wait(lambda: self._version != version, self.rng.uniform(*self.reaction_s)):
                    continue           # gone or moved before it was found
                if self._stop.is_set():
                    return
                goal = turned_left(direction_to(target.position, self.eye), self.miss_deg)
                if not self._turn_to(goal, version):
                    continue           # another target (or none) now: aim again
                self._press(target, goal)
                self._wait(lambda: self._version != version)       # found, or the trial over
                if self._shown is None:
                    self._turn_to(FRONT, self._version)
        except BaseException as exc:   # noqa: BLE001 - the test reports it
            self.errors.append(exc)

    def start(self) -> 'HeadsetParticipant':
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop acting (before the harness stops: its standard input is still open)."""
        self._stop.set()
        self._thread.join(10.0)
        self.read_log()

    def read_log(self) -> None:
        """What the harness logged since the last read (once it has stopped: the rest)."""
        self._pump()

    # ---- what the headset got
    def messages(self, kind: str) -> list[dict]:
        """The display messages of `kind` the harness logged (each with its receive time `t`)."""
        return [dict(e['msg'], t=e['t']) for e in self.entries if e.get('msg', {}).get('kind') == kind]

    def events(self, name: str) -> list[dict]:
        """The `event` messages named `name`, once per event_id (the first copy received)."""
        out: dict[int, dict] = {}
        for m in self.messages('event'):
            if m['event'] == name:
                out.setdefault(m['event_id'], m)
        return list(out.values())
