"""headset_display: what the wearer must see, sent to the HoloLens (docs/headset_wire_format.md).

It turns the graph's task state into display messages (core.display_wire) and sends them over
UDP to headset_address:display_port, and nowhere else:

- targets: target_markers (every target with its name and position; namespace live_targets for
  the micromanipulator's objects) and active_target, positions converted to Unity world; with
  `draw_targets` false (the paper's accuracy task: the target is never seen, the suit alone
  guides) no target is sent and `active` is empty: an inactive target would give away where
  the next one is (target_selector moves it before it makes it active); with `draw_inactive`
  false (a study session) only the active target is sent, none between targets;
- event: `next` when a target becomes active, `found` on target_found; each sent three times,
  EVENT_REPEAT_S apart, with one event_id, since UDP may lose one; each copy gets its seq when
  it is sent (display_wire.DisplaySender), so no copy is stale behind the messages sent between;
- dummies: with `dummies` > 0 (the paper's speed task: 50), a new seeded set for every newly
  active target (core.dummies), around the eye (eye_height_m above the origin, where the
  targets are placed from): at the active target's distance from the eye, in directions
  uniform in solid angle within +-dummy_azimuth_deg and +-dummy_elevation_deg of the front,
  never overlapping one another or the target (nor hiding them, seen from the eye); a field
  too small for that many gets as many as fit, with a warning. A set waits for the active
  target's position (target_markers); the first target_markers after an activation that shows
  the target elsewhere than the set was drawn around draws a new one (a marker overtaken by
  the activation);
- prompt: Algorithm 1's steps from calibration_state's fields (core.calibration_state.prompt:
  "Face front and rest", "Hold still: <direction>, step i of n"), cleared when it ends;
- phrase: condition 4's phrase from speech;
- from a study session (study_display): `prompt <text>` what to do now ("Look at the front",
  "Rest: the next trial starts soon"; `prompt` alone clears it; a calibration prompt replaces
  it), `found <target>` the accepted key press, `done <what>` the end of a sequence, a block or
  the session (event `done`, target `sequence`, `block` or `session`).

targets, dummies, prompt and phrase are sent on change and again at refresh_hz, whole, so a
lost datagram or a restarted app is repaired within one refresh. /diagnostics counts what was
sent by kind and the send errors.

Subscribed: target_markers (visualization_msgs/MarkerArray), active_target, target_found,
            calibration_state, speech, study_display (std_msgs/String)
Published:  /diagnostics; UDP datagrams to headset_address:display_port
"""
from __future__ import annotations

import ipaddress
import math
import socket
import sys
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
import numpy as np
from rclpy.node import Node
from std_msgs.msg import String
from visualization_msgs.msg import Marker, MarkerArray

from fabric_guidance.core import calibration_state, display_wire, dummies
from fabric_guidance.interface import (ACTIVE_TARGET, CALIBRATION_STATE, DIAGNOSTICS, SPEECH, STUDY_DISPLAY,
                                       TARGET_FOUND, TARGET_MARKERS)
from fabric_guidance.nodes.diagnostics import publish_diagnostics, status
from fabric_guidance.nodes.parameters import declare
from fabric_guidance.nodes.qos import EVENT_QOS, LATCHED_QOS
from fabric_guidance.nodes.spin import run

#: Each event is sent this many times, EVENT_REPEAT_S apart (the headset shows each id once).
EVENT_SENDS = 3
EVENT_REPEAT_S = 0.02
#: The marker namespace of the micromanipulator's live objects (target_selector).
LIVE_NAMESPACE = 'live_targets'
#: The radius the headset draws a target with (DisplayRenderer.targetDiameterM 0.1 m): dummies keep clear of it.
TARGET_RADIUS_M = 0.05
#: The first target_markers after an activation showing the target this far from where its
#: dummies were drawn around gets a new set (less: the same place, as on the wire within 0.1 mm).
MOVED_M = 1e-3


class HeadsetDisplay(Node):

    def __init__(self, **kwargs):   # kwargs: Node's (a test's context, parameter_overrides)
        super().__init__('headset_display', **kwargs)
        address = declare(self, 'headset_address', '127.0.0.1', "the HoloLens's IP address (the only destination)",
                          read_only=True)
        port = declare(self, 'display_port', 5006, "the headset's downlink UDP port", '-', 1, 65535, read_only=True)
        refresh_hz = declare(self, 'refresh_hz', 2.0, 'the whole display state is sent again this often', 'Hz',
                             0.1, 50.0, read_only=True)
        self.dummies = declare(self, 'dummies', 0, "distractor spheres per target (the paper's speed task: 50)",
                               '-', 0, display_wire.MAX_DUMMIES_PER_PART * display_wire.MAX_DUMMY_PARTS,
                               read_only=True)
        self.dummy_seed = declare(self, 'dummy_seed', 0, 'seed of the dummy positions', '-', 0, 2 ** 31 - 1,
                                  read_only=True)
        self.dummy_radius_m = declare(self, 'dummy_radius_m', 0.05, 'dummy sphere radius', 'm', 0.001, 1.0,
                                      read_only=True)
        self.dummy_azimuth_deg = declare(self, 'dummy_azimuth_deg', 60.0, 'dummies within +- this azimuth of the '
                                         'front', 'deg', 0.0, 180.0, read_only=True)
        self.dummy_elevation_deg = declare(self, 'dummy_elevation_deg', 30.0, 'dummies within +- this elevation',
                                           'deg', 0.0, 90.0, read_only=True)
        self.eye_height_m = declare(self, 'eye_height_m', 1.2, 'gaze origin above the immersive origin (the '
                                    'dummies are placed around it)', 'm', 0.0, 3.0, read_only=True)
        # Set by a study session before each target too (a parameter: set before the target
        # is, so no refresh can draw an unseen target in between).
        self.draw_targets = declare(self, 'draw_targets', True, "draw the targets (false: the paper's accuracy "
                                    'task, an unseen target reached by guidance alone; nothing drawn or named)')
        # A study's one target stays in target_markers where it last was between its trials: a
        # participant would see last trial's target (magenta) through every rest.
        self.draw_inactive = declare(self, 'draw_inactive', True, 'draw the targets that are not active (false: '
                                     'the active one only, none between targets: a study session)', read_only=True)
        self.add_post_set_parameters_callback(self.on_parameters)
        try:
            ip = ipaddress.ip_address(address)
        except ValueError:
            raise ValueError(f"parameter 'headset_address': {address!r} is not an IP address") from None
        self.destination = (str(ip), port)
        self._sock = socket.socket(socket.AF_INET6 if ip.version == 6 else socket.AF_INET, socket.SOCK_DGRAM)
        if ip.is_loopback:
            # Sending alone would bind the socket to every interface: reachable from the network.
            self._sock.bind((str(ip), 0))

        self.active = ''
        self.targets: list[dict] = []          # {'id', 'position' (Unity), 'role'}, target_markers' order
        self.dummy_set = 0
        self.dummy_positions: list[list[float]] = []   # Unity
        self._drawn_around: list[float] | None = None   # the target (REP 103) the set was drawn around
        self._await_markers = False            # the first target_markers after an activation not seen yet
        self.prompt = ('', 0, 0)
        self.phrase = ''
        self._wire = display_wire.DisplaySender(EVENT_SENDS, EVENT_REPEAT_S)   # seq, event ids, repeats
        self.sent = {kind: 0 for kind in display_wire.KINDS}
        self.send_errors = 0
        self.bytes_sent = 0
        self.bad_states = 0

        self.create_subscription(MarkerArray, TARGET_MARKERS, self.on_markers, LATCHED_QOS)
        self.create_subscription(String, ACTIVE_TARGET, self.on_active, LATCHED_QOS)
        self.create_subscription(String, TARGET_FOUND, self.on_found, EVENT_QOS)
        self.create_subscription(String, CALIBRATION_STATE, self.on_calibration, LATCHED_QOS)
        self.create_subscription(String, SPEECH, self.on_speech, EVENT_QOS)
        self.create_subscription(String, STUDY_DISPLAY, self.on_study, EVENT_QOS)
        self._diag_pub = self.create_publisher(DiagnosticArray, DIAGNOSTICS, 10)
        self.create_timer(1.0 / refresh_hz, self.send_state)
        self.create_timer(EVENT_REPEAT_S, self._send_repeats)
        self.create_timer(1.0, self._publish_diagnostics)
        self.get_logger().info(f'display messages to {self.destination[0]}:{self.destination[1]}, refreshed at '
                               f'{refresh_hz} Hz; {self.dummies} dummies per target')

    # --- sending --------------------------------------------------------------------------

    def _stamp(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    def _send(self, kind: str, **fields) -> bytes:
        data = self._wire.encode(kind, self._stamp(), **fields)
        self._send_bytes(kind, data)
        return data

    def _send_bytes(self, kind: str, data: bytes) -> None:
        try:
            self._sock.sendto(data, self.destination)
        except OSError as exc:   # no route to the headset yet: the refresh tries again
            self.send_errors += 1
            self.get_logger().warn(f'display message to {self.destination[0]}:{self.destination[1]} failed: {exc}',
                                   throttle_duration_sec=10.0)
            return
        self.sent[kind] += 1
        self.bytes_sent += len(data)

    def shown(self) -> tuple[str, list[dict]]:
        """The active target's id and the targets as the headset is to draw them."""
        if not self.draw_targets:
            return '', []
        if not self.draw_inactive:
            return self.active, [t for t in self.targets if t['id'] == self.active]
        return self.active, self.targets

    def send_targets(self) -> None:
        active, targets = self.shown()
        self._send('targets', active=active, targets=targets)

    def send_state(self) -> None:
        """The whole display state, as on every refresh."""
        self.send_targets()
        self.send_dummies()
        text, step, steps = self.prompt
        self._send('prompt', text=text, step=step, steps=steps)
        self._send('phrase', text=self.phrase)

    def send_dummies(self) -> None:
        per = display_wire.MAX_DUMMIES_PER_PART
        parts = max(1, math.ceil(len(self.dummy_positions) / per))
        for part in range(parts):
            self._send('dummies', set=self.dummy_set, part=part, parts=parts, radius_m=self.dummy_radius_m,
                       positions=self.dummy_positions[part * per:(part + 1) * per])

    def event(self, name: str, target: str) -> None:
        self._send_bytes('event', self._wire.event(name, target, time.monotonic(), self._stamp()))

    def _send_repeats(self) -> None:
        for data in self._wire.due(time.monotonic(), self._stamp()):
            self._send_bytes('event', data)

    # --- callbacks ------------------------------------------------------------------------

    def on_markers(self, msg: MarkerArray) -> None:
        targets = []
        for m in msg.markers:
            if m.action != Marker.ADD or not m.text:
                continue
            p = m.pose.position
            if not all(math.isfinite(c) for c in (p.x, p.y, p.z)):
                continue
            targets.append({'id': m.text, 'position': display_wire.to_unity((p.x, p.y, p.z)),
                            'role': 'live' if m.ns == LIVE_NAMESPACE else 'target'})
        if len(targets) > display_wire.MAX_TARGETS:
            self.get_logger().warn(f'{len(targets)} targets: the headset is sent the first '
                                   f'{display_wire.MAX_TARGETS} (docs/headset_wire_format.md)', once=True)
        changed = targets != self.targets
        self.targets = targets
        if changed:
            self.send_targets()
        target = self.active_position()
        if self._await_markers and target is not None:
            self._await_markers = False
            if self._drawn_around is None or math.dist(target, self._drawn_around) > MOVED_M:
                self.new_dummies()
                self.send_dummies()

    def on_active(self, msg: String) -> None:
        if msg.data == self.active:
            return
        self.active = msg.data
        self._drawn_around = None
        self._await_markers = bool(self.active and self.dummies)
        if self._await_markers:
            self.new_dummies()
        self.send_targets()
        if self.dummies:
            self.send_dummies()
        if self.active:
            # an unseen target is not named either: the wearer learns a trial began, not where
            self.event('next', self.shown()[0])

    def active_position(self) -> list[float] | None:
        """The active target's position (REP 103) as target_markers last gave it; None if not."""
        for t in self.targets:
            if t['id'] == self.active:
                return display_wire.from_unity(t['position'])
        return None

    def new_dummies(self) -> None:
        """A new set around the active target, once its position is known (else on_markers draws it)."""
        target = self.active_position()
        if target is None:
            return
        self.dummy_set = self.dummy_set % (display_wire.UINT32 - 1) + 1
        self.dummy_positions = self.draw_dummies(self.dummy_set, target)
        self._drawn_around = target

    def draw_dummies(self, dummy_set: int, target) -> list[list[float]]:
        """The dummy positions of a set (Unity world) around the eye: seeded by dummy_seed and the set number."""
        rng = np.random.default_rng([self.dummy_seed, dummy_set])
        eye = (0.0, 0.0, self.eye_height_m)     # REP 103: x forward, y left, z up
        placed = dummies.around_eye(rng, self.dummies, eye, target, self.dummy_radius_m, TARGET_RADIUS_M,
                                    self.dummy_azimuth_deg, self.dummy_elevation_deg)
        if len(placed) < self.dummies:
            self.get_logger().warning(
                f'only {len(placed)} of {self.dummies} dummies fit apart around a target '
                f'{math.dist(target, eye):.2f} m from the eye: the field is too small for them (parameters '
                'dummies, dummy_radius_m, dummy_azimuth_deg, dummy_elevation_deg, eye_height_m)', once=True)
        return [display_wire.to_unity(p) for p in placed]

    def on_found(self, msg: String) -> None:
        self.event('found', msg.data)

    def on_calibration(self, msg: String) -> None:
        try:
            state = calibration_state.decode(msg.data)
        except calibration_state.CalibrationStateError as exc:
            self.bad_states += 1
            self.get_logger().warn(f'{exc}: the prompt is left as it is', throttle_duration_sec=10.0)
            return
        prompt = calibration_state.prompt(state)
        if prompt != self.prompt:
            self.prompt = prompt
            self._send('prompt', text=prompt[0], step=prompt[1], steps=prompt[2])

    def on_parameters(self, parameters) -> None:
        for p in parameters:
            if p.name == 'draw_targets' and bool(p.value) != self.draw_targets:
                self.draw_targets = bool(p.value)
                self.send_targets()

    def on_study(self, msg: String) -> None:
        """A study session's line: `prompt [text]`, `found <target>` or `done [what]`."""
        word, _, rest = msg.data.partition(' ')
        if word == 'prompt' and len(rest) <= display_wire.MAX_TEXT_CHARS:
            self.prompt = (rest, 0, 0)
            self._send('prompt', text=rest, step=0, steps=0)
        elif word in ('found', 'done') and len(rest) <= display_wire.MAX_ID_CHARS:
            self.event(word, rest)
        else:
            self.get_logger().warn(f'study_display: {msg.data[:60]!r} ignored: not `prompt [text]` (text up to '
                                   f'{display_wire.MAX_TEXT_CHARS} characters), `found <target>` or `done [what]`',
                                   throttle_duration_sec=5.0)

    def on_speech(self, msg: String) -> None:
        self.phrase = msg.data
        self._send('phrase', text=self.phrase)

    # --- diagnostics and shutdown -------------------------------------------------------------

    def _publish_diagnostics(self) -> None:
        level = DiagnosticStatus.WARN if self.send_errors else DiagnosticStatus.OK
        values = {'destination': f'{self.destination[0]}:{self.destination[1]}', 'active': self.active,
                  'targets': len(self.targets), 'dummy_set': self.dummy_set, 'dummies': len(self.dummy_positions),
                  'send_errors': self.send_errors,
                  'bytes_sent': self.bytes_sent, 'bad_calibration_states': self.bad_states,
                  **{f'sent_{k}': n for k, n in self.sent.items()}}
        message = f'{sum(self.sent.values())} display messages sent' + (
            f', {self.send_errors} failed' if self.send_errors else '')
        publish_diagnostics(self, self._diag_pub, [status(
            self, 'display', level, message, values, hardware_id=f'HoloLens {self.destination[0]}')])

    def destroy_node(self):
        self._sock.close()
        return super().destroy_node()


def main(args=None):
    return run(lambda: HeadsetDisplay(), args)


if __name__ == '__main__':
    sys.exit(main())
