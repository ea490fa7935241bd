"""The soak run's gaze-to-register latency without ROS: which control step a gaze sample led to,
which command that step published, and when the mock PLC applied it (soak.md defines it)."""
from __future__ import annotations

from collections import Counter, deque
from dataclasses import dataclass
import threading

LATENCY = ("gaze-to-register latency: for every control step on a new gaze sample (a gaze direction unlike "
           "the step before's) whose command changed the PLC's command registers, the time the mock PLC "
           "applied that command (its register log, CLOCK_MONOTONIC) minus the sample's capture time as "
           "gaze_bridge stamps it (wearer_sim's send time through the bridge's clock estimate, within its "
           "clock_bound_ms). Steps on a repeated gaze or on the controller's timer, and commands that "
           "changed nothing, have no latency: while the wearer closes in, Eq. 5 holds the command, so this "
           "comes about once per target. Gaze-to-command (command_*): the same capture time to the "
           "publication of that step's pressure_command (its DDS source time), for every step on a new "
           "gaze sample, changed or not.")

#: A changed command not applied at the registers this long after it was published is lost [s].
LAND_TIMEOUT_S = 1.0
#: A command waits this long for the control step it belongs to (published just before it) [s].
PAIR_WAIT_S = 0.5
#: Gaze samples kept to find a step's sample (about 17 s at 60 Hz).
GAZE_KEEP = 1024


@dataclass
class Pending:
    """A changed command on its way to the registers."""
    published_ns: int          # CLOCK_MONOTONIC
    counts: tuple[int, ...]
    capture_ns: int | None     # its gaze sample's capture (CLOCK_MONOTONIC); None: no new sample


class LatencyMatcher:
    """Gaze samples, control steps (controller_input), commands (pressure_command) and the mock
    PLC's register log in; one latency per sample whose command changed the registers out.

    A command belongs to the last step published before it (the controller publishes a step's
    input, then its command); the step's gaze is the latest sample with the same direction
    captured before the step. The command lands at the first register change after its
    publication that holds exactly its counts. Times are CLOCK_MONOTONIC [ns]; the feed methods
    are called from the probe's thread, `update` from the run's."""

    def __init__(self, encode, vented: tuple[int, ...]):
        self.encode = encode
        self._lock = threading.Lock()
        self._captures: dict[tuple, list[int]] = {}
        self._order: deque = deque()
        self._inputs: deque = deque()       # (published_ns, step, direction key)
        self._commands: deque = deque()     # (published_ns, counts)
        self._registers: deque = deque()    # (applied_ns, counts), client writes only
        self._pending: deque[Pending] = deque()
        self._last_counts = vented          # the PLC powers up vented
        self._last_key = None
        self._last_step: int | None = None
        self.latencies: list[tuple[int, int]] = []   # (capture_ns, latency_ns): gaze to register
        self.to_command: list[tuple[int, int]] = []   # (capture_ns, latency_ns): gaze to command
        self.counts = Counter()

    # ---- feeds
    def gaze(self, key: tuple, capture_ns: int) -> None:
        with self._lock:
            self._captures.setdefault(key, []).append(capture_ns)
            self._order.append(key)
            if len(self._order) > GAZE_KEEP:
                old = self._order.popleft()
                kept = self._captures[old]
                kept.pop(0)
                if not kept:
                    del self._captures[old]

    def step(self, published_ns: int, step: int, key: tuple) -> None:
        with self._lock:
            if self._last_step is not None and step > self._last_step + 1:
                self.counts['steps_unseen'] += step - self._last_step - 1
            self._last_step = step
            self.counts['steps'] += 1
            self._inputs.append((published_ns, step, key))

    def command(self, published_ns: int, kpa) -> None:
        counts = tuple(self.encode(kpa))
        with self._lock:
            self._commands.append((published_ns, counts))

    def registers(self, applied_ns: int, counts: tuple[int, ...]) -> None:
        with self._lock:
            self._registers.append((applied_ns, counts))

    # ---- matching
    def update(self, now_ns: int, drained_ns: int) -> None:
        """Pair what has arrived and land what the register log covers (drained_ns)."""
        with self._lock:
            self._pair(now_ns)
            self._land(drained_ns)

    def _pair(self, now_ns: int) -> None:
        wait_ns = int(PAIR_WAIT_S * 1e9)
        while self._commands:
            published, counts = self._commands[0]
            # Its step is published first, but may arrive after it on another topic.
            if not (self._inputs and self._inputs[-1][0] > published) and now_ns - published < wait_ns:
                return
            self._commands.popleft()
            step = None
            while self._inputs and self._inputs[0][0] <= published:
                step = self._inputs.popleft()
            capture = None
            if step is not None and step[2] != self._last_key:
                capture = max((c for c in self._captures.get(step[2], ()) if c <= step[0]), default=None)
                if capture is None:
                    self.counts['unmatched'] += 1
                else:
                    self.to_command.append((capture, published - capture))
            if step is not None:
                self._last_key = step[2]
            if counts != self._last_counts:
                self._last_counts = counts
                self.counts['changed'] += 1
                self._pending.append(Pending(published, counts, capture))

    def _land(self, drained_ns: int) -> None:
        timeout_ns = int(LAND_TIMEOUT_S * 1e9)
        while self._pending:
            p = self._pending[0]
            hit = next((i for i, (t, c) in enumerate(self._registers) if t >= p.published_ns and c == p.counts), None)
            if hit is not None:
                applied = self._registers[hit][0]
                for _ in range(hit + 1):
                    self._registers.popleft()
                self._pending.popleft()
                if p.capture_ns is not None:
                    self.latencies.append((p.capture_ns, applied - p.capture_ns))
            elif drained_ns >= p.published_ns + timeout_ns:
                self._pending.popleft()
                self.counts['not_landed'] += 1
            else:
                return
        # Nothing waits: changes older than any command to come are nobody's any more.
        while self._registers and self._registers[0][0] < drained_ns - timeout_ns:
            self._registers.popleft()

    def settled(self, until_ns: int) -> bool:
        """Every command published before until_ns has been paired and landed (or given up)."""
        with self._lock:
            return not ((self._commands and self._commands[0][0] < until_ns)
                        or (self._pending and self._pending[0].published_ns < until_ns))

    def take(self, until_ns: int) -> tuple[list[int], list[int], Counter]:
        """Gaze-to-register and gaze-to-command latencies [ns] of samples captured before
        until_ns, and the counts so far (all handed over: the next call starts from zero)."""
        with self._lock:
            taken = [lat for c, lat in self.latencies if c < until_ns]
            self.latencies = [(c, lat) for c, lat in self.latencies if c >= until_ns]
            to_command = [lat for c, lat in self.to_command if c < until_ns]
            self.to_command = [(c, lat) for c, lat in self.to_command if c >= until_ns]
            counts, self.counts = self.counts, Counter()
        return taken, to_command, counts
