"""The package's ROS interface in one place: every topic and service name, its type, its QoS
kind, who publishes and who listens, and the immersive frame. The nodes take their names from
here, the bag code also the types and QoS kinds, and docs/interfaces.md its tables
(`python -m fabric_guidance.interface --markdown` prints the tables).

Names follow ROS's conventions, so that two suits run side by side in two namespaces of one
domain (docs/interfaces.md, "Names and namespaces"): the graph's data flow is on relative topic
names (resolved in the node's namespace); what belongs to one node, its services and the mock
PLC's test output, is private to it (`~/enable`: `/<namespace>/pressure_controller/enable`).
A client names them through `full_name()`, never by hand.

No rclpy at import: the bag code and the docs use this module without ROS; qos_profile()
builds the rclpy profile of a kind when a node asks for it.
"""
from __future__ import annotations

from dataclasses import dataclass
import sys

# Topic and service names, relative so that a namespace or a remap moves them together.
GAZE = 'gaze'
HEAD_POSE = 'head_pose'
TARGET = 'target'
ACTIVE_TARGET = 'active_target'
TARGET_FOUND = 'target_found'
TARGET_MARKERS = 'target_markers'
LIVE_TARGETS = 'live_targets'
PRESSURE_COMMAND = 'pressure_command'
MEASURED_PRESSURE = 'measured_pressure'
SPEECH = 'speech'
CALIBRATION_STATUS = 'calibration_status'
CALIBRATION_STATE = 'calibration_state'
CONFIRM = 'confirm'
DIAGNOSTICS = '/diagnostics'
CONTROLLER_INPUT = 'controller_input'
CONTROLLER_PARAMETERS = 'controller_parameters'
CLOCK = '/clock'
MAX_WRITTEN = '~/max_written_kpa'
HEADSET_VIEW = 'headset_view'
STUDY_DISPLAY = 'study_display'

# Services: private to the node that answers them (the table's `node`).
START_CALIBRATION = '~/start_calibration'
ENABLE = '~/enable'
VENT = '~/vent'
TRIAL_GATE = '~/trial_gate'
NEXT_TARGET = '~/next_target'
RESET_SEQUENCE = '~/reset_sequence'

#: Names before the namespace change (a client or script written for them): old -> new, as
#: docs/interfaces.md's migration note lists them. The old names are served no more.
OLD_NAMES = {
    '/start_calibration': START_CALIBRATION, '/enable': ENABLE, '/vent': VENT,
    '/next_target': NEXT_TARGET, '/reset_sequence': RESET_SEQUENCE, '/mock_plc/max_written_kpa': MAX_WRITTEN,
}

#: The lifecycle (managed) nodes: the standard lifecycle services and transition_event are
#: theirs (docs/lifecycle.md); launch files drive them, the security policy grants them.
MANAGED_NODES = ('pressure_controller', 'plc_output')

#: The frame of the immersive space (REP 103 axes, Unity's world origin).
IMMERSIVE_FRAME = 'immersive'

# QoS kinds. sensor: a late gaze sample is worth nothing (best effort, newest only). command:
# reliable, a short queue (ros2_controllers' command topics use reliable depth 10). latched:
# state a late joiner must see (reliable, transient local, 1). event: must not be lost
# (reliable, a longer queue). default: rclpy's depth 10 reliable volatile (/diagnostics).
# clock: /clock of a replay (best effort, the newest only).
SENSOR, COMMAND, LATCHED, EVENT, DEFAULT, CLOCK_KIND = (
    'sensor', 'command', 'latched', 'event', 'default', 'clock')

#: kind -> (reliable, transient local, depth); sensor is rclpy's qos_profile_sensor_data.
QOS_KINDS: dict[str, tuple[bool, bool, int]] = {
    SENSOR: (False, False, 5),
    COMMAND: (True, False, 10),
    LATCHED: (True, True, 1),
    EVENT: (True, False, 50),
    DEFAULT: (True, False, 10),
    CLOCK_KIND: (False, False, 1),
}

_QOS_TEXT = {
    SENSOR: 'sensor data (best effort, keep last 5)',
    COMMAND: 'reliable, depth 10',
    LATCHED: 'reliable, transient local, depth 1',
    EVENT: 'reliable, depth 50',
    DEFAULT: 'reliable, depth 10',
    CLOCK_KIND: 'best effort, depth 1',
}


def qos_profile(kind: str):
    """The rclpy QoSProfile of a QoS kind (KeyError naming the kinds for an unknown one)."""
    if kind not in QOS_KINDS:
        raise KeyError(f'unknown QoS kind {kind!r}; kinds: {sorted(QOS_KINDS)}')
    from rclpy.qos import (DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy,
                           qos_profile_sensor_data)
    if kind == SENSOR:
        return qos_profile_sensor_data
    reliable, latched, depth = QOS_KINDS[kind]
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth,
                      reliability=(ReliabilityPolicy.RELIABLE if reliable
                                   else ReliabilityPolicy.BEST_EFFORT),
                      durability=(DurabilityPolicy.TRANSIENT_LOCAL if latched
                                  else DurabilityPolicy.VOLATILE))


@dataclass(frozen=True)
class Topic:
    name: str
    type: str            # ROS type, package/msg/Name
    qos: str             # QoS kind
    publishers: str
    subscribers: str
    what: str
    recorded: bool = True  # bag_recorder records it (bag/topics.py TOPICS)
    type_note: str = ''    # shown after the type in the docs, e.g. the payload's format
    qos_note: str = ''     # shown after the QoS in the docs


@dataclass(frozen=True)
class Service:
    name: str
    type: str            # ROS type, package/srv/Name
    node: str
    what: str


TOPICS: tuple[Topic, ...] = (
    Topic(GAZE, 'geometry_msgs/msg/PoseStamped', SENSOR, 'gaze_bridge',
          'target_selector, pressure_controller',
          'position: gaze origin [m]; orientation: x axis along the gaze ray, no roll; '
          "stamp: the headset's capture time once its clock is estimated "
          '([headset_wire_format.md](headset_wire_format.md)), the receive time before'),
    Topic(HEAD_POSE, 'geometry_msgs/msg/PoseStamped', SENSOR, 'gaze_bridge', '',
          'HoloLens head pose [m]; published only while something subscribes'),
    Topic(TARGET, 'geometry_msgs/msg/PointStamped', LATCHED, 'target_selector',
          'pressure_controller, wearer_sim (with a scene)',
          'active target position [m]; republished at 10 Hz'),
    Topic(ACTIVE_TARGET, 'std_msgs/msg/String', LATCHED, 'target_selector',
          'pressure_controller, wearer_sim, headset_display',
          "name of the active target, `''` for none; a reader that must see every change in turn (wearer_sim, "
          'the demo) keeps 10 (nodes/qos.py LATCHED_ALL_QOS): a reader of depth 1 late to take them keeps only '
          'the newest'),
    Topic(TARGET_FOUND, 'std_msgs/msg/String', EVENT, 'target_selector', 'headset_display',
          'a target the wearer just found'),
    Topic(TARGET_MARKERS, 'visualization_msgs/msg/MarkerArray', LATCHED, 'target_selector',
          'RViz, headset_display', 'targets as 0.1 m spheres (active red, others magenta), the name in '
          '`text`; namespace `targets` (fixed) or `live_targets`'),
    Topic(LIVE_TARGETS + '/<name>', 'geometry_msgs/msg/PoseStamped', SENSOR,
          'micromanipulator stack, or micromanipulator_sim', 'target_selector',
          'live targets in the microscope frame [m] (`live_frame_id`), scaled by `live_scale` and shifted by '
          '`live_offset`; in the immersive frame taken as is; in any other frame refused', recorded=False,
          qos_note='matches reliable publishers too'),
    Topic(PRESSURE_COMMAND, 'std_msgs/msg/Float64MultiArray', COMMAND, 'pressure_controller',
          'plc_output', 'kPa per channel, in the order of the `channels` parameter: F1-F4, '
          'B1-B4, L1-L2, R1-R2, arm_i-arm_vi; `layout.dim[0].label` names them in that order, '
          'comma-separated ([array labels](#array-labels)); plc_output writes only the commands of '
          "its graph's pressure_controller, labelled in its channel order, aged from their source "
          'timestamp ([safety.md](safety.md#where-a-command-comes-from))'),
    Topic(MEASURED_PRESSURE, 'std_msgs/msg/Float64MultiArray', COMMAND, 'plc_output',
          'wearer_sim', "regulators' measured kPa, same order and label"),
    Topic(SPEECH, 'std_msgs/msg/String', EVENT, 'pressure_controller',
          'wearer_sim (with a scene, condition 4), headset_display', "condition 4's phrase, once per target"),
    Topic(CALIBRATION_STATUS, 'std_msgs/msg/String', EVENT, 'pressure_controller', '',
          'for people (`ros2 topic echo`): `rest before <direction> step 0/<n> 0 kPa <percent>%` '
          '(vented, face front) and '
          '`apply <direction> step <i>/<n> <P> kPa <percent>%` while running; '
          '`done: <file>; fit report <txt>, <png>` or '
          '`failed: <reason>; the previous calibration is kept (<its wearer>)` or, with none, '
          '`failed: <reason>; no previous calibration of <wearer>: no guidance until one succeeds`'),
    Topic(CALIBRATION_STATE, 'std_msgs/msg/String', LATCHED, 'pressure_controller',
          'headset_display, wearer_sim (goes with the suit while a calibration step pulls, faces the front '
          'in its rests), the study session',
          "the live calibration's progress and outcome as fields: phase (`idle`, `rest`, `apply`, `done`, "
          '`failed`, `refused`), direction, step of steps, pressure [kPa], progress 0..1, file, report, error, '
          'previous_kept ([calibration state](#calibration-state)); the sentence on `calibration_status` is '
          'for people', type_note='(one JSON object)'),
    Topic(CONFIRM, 'std_msgs/msg/Header', EVENT, 'gaze_bridge, wearer_sim, the study session', 'the study session',
          "the wearer's confirm press (\"I am there\"): stamp = when it was pressed (the headset's capture "
          'time on the PC clock, as `gaze`; the receive time before the clock is estimated), frame_id = '
          "its source (`headset`: the clicker or an air tap, [headset_wire_format.md](headset_wire_format.md); "
          "`keyboard`: the operator's key, sent by the study session; `wearer_sim`)"),
    Topic(DIAGNOSTICS, 'diagnostic_msgs/msg/DiagnosticArray', DEFAULT,
          'gaze_bridge, target_selector, pressure_controller, plc_output, mock_plc, '
          'bag_recorder, headset_display', '',
          "bridge counts by drop reason and loss rate, the headset clock's offset, drift and bound, "
          'the one-way delay from capture; display messages sent by kind; task state; controller state and vent '
          'reason; PLC link state and round-trip time; mock PLC violations; messages recorded '
          'per topic'),
    Topic(CONTROLLER_INPUT, 'std_msgs/msg/Float64MultiArray', COMMAND, 'pressure_controller',
          'bag_recorder', 'every control step: the exact inputs it used (layout in '
          '[recording_and_replay.md](recording_and_replay.md), its field names in '
          '`layout.dim[0].label`); published only while something subscribes'),
    Topic(CONTROLLER_PARAMETERS, 'std_msgs/msg/String', LATCHED, 'pressure_controller',
          'bag_recorder', 'parameters, calibration and channel map, for offline replay',
          type_note='(YAML)'),
    Topic(CLOCK, 'rosgraph_msgs/msg/Clock', CLOCK_KIND, '`fabric-guidance replay`',
          'nodes with `use_sim_time`', "the bag's time", recorded=False),
    Topic(HEADSET_VIEW, 'std_msgs/msg/String', EVENT, 'wearer_sim', 'the demo, tests',
          'what the simulated headset newly shows the wearer, a line each: `next <target>`, '
          '`found <target>`, `dummies <n>`, `prompt <text> (<i>/<n>)`, `phrase <text>`, '
          '`targets <n>, active <name>`', recorded=False),
    Topic(STUDY_DISPLAY, 'std_msgs/msg/String', EVENT, 'the study session', 'headset_display',
          'what the session shows the wearer, a line each: `prompt <text>` (`prompt` alone clears it), '
          '`found <target>`, `done`'),
    Topic(MAX_WRITTEN, 'std_msgs/msg/Float64MultiArray', COMMAND, 'mock_plc', 'tests',
          "largest value ever written per channel [kPa], in the register map's order, labelled "
          'as `pressure_command`', recorded=False),
)

SERVICES: tuple[Service, ...] = (
    Service(START_CALIBRATION, 'std_srvs/srv/Trigger', 'pressure_controller',
            'run Algorithm 1 live with the wearer (refused without a fresh gaze); writes '
            '`<calibration_dir>/<wearer>.yaml` only if every direction fits; progress on '
            '`calibration_status`; a stale gaze aborts it vented'),
    Service(ENABLE, 'std_srvs/srv/SetBool', 'pressure_controller',
            "the operator's arm: true arms (a person's act; it starts nothing by itself), false vents and "
            'holds until the next `enable true`; off at every start with `start_enabled false` '
            '([safety.md](safety.md#latches-and-limits))'),
    Service(VENT, 'std_srvs/srv/Trigger', 'pressure_controller',
            "vent at once and drop the operator's arm: nothing guides until `enable`"),
    Service(TRIAL_GATE, 'std_srvs/srv/SetBool', 'pressure_controller',
            "the study session's gate for its rests (false: vents) and trials (true); pressure flows only "
            "while the operator's arm and this gate are both open; opening it never arms (its answer is "
            "not successful while the arm is off); open at every start"),
    Service(NEXT_TARGET, 'std_srvs/srv/Trigger', 'target_selector',
            'activate the next target of the sequence'),
    Service(RESET_SEQUENCE, 'std_srvs/srv/Trigger', 'target_selector', 'back to the first target'),
)


def owner(name: str) -> str:
    """The node a private (`~/`) name of the tables belongs to (KeyError naming the private names)."""
    for s in SERVICES:
        if s.name == name:
            return s.node
    for t in TOPICS:
        if t.name == name and name.startswith('~/'):
            return t.publishers
    private = [s.name for s in SERVICES] + [t.name for t in TOPICS if t.name.startswith('~/')]
    raise KeyError(f'{name!r} is no private name of the interface; private names: {private}')


def full_name(name: str, namespace: str = '', node: str | None = None) -> str:
    """The fully qualified name a client in any namespace uses for `name` of the graph in
    `namespace` ('' or '/' for the root): a private name (`~/enable`) of `node` (by default the
    node the tables give it), a relative one (`target`) in the namespace, an absolute one as is.

        full_name(ENABLE, 'suit_a') == '/suit_a/pressure_controller/enable'
    """
    ns = '/'.join(part for part in namespace.split('/') if part)
    prefix = f'/{ns}' if ns else ''
    if name.startswith('/'):
        return name
    if name.startswith('~/'):
        return f'{prefix}/{node or owner(name)}/{name[2:]}'
    return f'{prefix}/{name}'


def topic(name: str) -> Topic:
    """The Topic of a name (KeyError naming the known ones)."""
    for t in TOPICS:
        if t.name == name:
            return t
    raise KeyError(f'unknown topic {name!r}; topics: {[t.name for t in TOPICS]}')


def _short_type(ros_type: str) -> str:
    package, _, name = ros_type.split('/')
    return f'{package}/{name}'


def markdown() -> str:
    """The topic and service tables of docs/interfaces.md."""
    lines = ['| topic | type | QoS | publisher | subscribers | what |',
             '| --- | --- | --- | --- | --- | --- |']
    for t in TOPICS:
        ros_type = ' '.join(filter(None, (_short_type(t.type), t.type_note)))
        qos = '; '.join(filter(None, (_QOS_TEXT[t.qos], t.qos_note)))
        lines.append(f'| `{t.name}` | {ros_type} | {qos} | {t.publishers} | {t.subscribers} '
                     f'| {t.what} |')
    lines += ['', '| service | type | node | what |', '| --- | --- | --- | --- |']
    for s in SERVICES:
        lines.append(f'| `{s.name}` | {_short_type(s.type)} | {s.node} | {s.what} |')
    lines += ['', '| old name (before namespaces) | name now | in the root namespace |', '| --- | --- | --- |']
    for old, new in OLD_NAMES.items():
        lines.append(f'| `{old}` | `{new}` | `{full_name(new)}` |')
    return '\n'.join(lines) + '\n'


def markdown_main(module: str, tables, argv: list[str] | None = None) -> int:
    """`python -m <module> --markdown`: print the docs tables `tables()` generates."""
    argv = sys.argv[1:] if argv is None else argv
    if argv != ['--markdown']:
        print(f'usage: python -m {module} --markdown', file=sys.stderr)
        return 2
    sys.stdout.write(tables())
    return 0


def main(argv: list[str] | None = None) -> int:
    return markdown_main('fabric_guidance.interface', markdown, argv)


if __name__ == '__main__':
    sys.exit(main())
