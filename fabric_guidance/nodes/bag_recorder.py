"""bag_recorder: records a guided session as a ROS 2 bag (rosbag2, MCAP storage) with the
message definitions and the QoS profiles `ros2 bag play` and Foxglove need. Runs beside the
lab launch or the demo graph (`fabric-guidance demo --record DIR`); no rosbag2 install needed.

Subscribes  every topic of fabric_guidance/bag/topics.py TOPICS (or the `topics` parameter):
            gaze, head_pose, target, active_target, target_found, target_markers,
            pressure_command, measured_pressure, speech, calibration_status, calibration_state,
            confirm, /diagnostics,
            controller_input, controller_parameters; each with its publishers' QoS (latched ones
            transient local)
Publishes   /diagnostics (diagnostic_msgs/DiagnosticArray) every diagnostics_period_s:
            'bag_recorder: recording' with the bag path and the messages written per topic
            (a session script waits on it to know the recorder hears the controller)
Writes      <output> (or <output_dir>/session_<UTC time>), closed with its metadata.yaml on
            SIGINT/SIGTERM; every flush_period_s what it received is put on disk as a complete
            MCAP chunk, so a recorder killed without warning (SIGKILL, power loss) loses at most
            that last period (`fabric-guidance recover` makes the rest a complete bag)

Messages are stored as received (serialized CDR, no decoding), stamped with the receive time
on the node clock (sim time under use_sim_time), as `ros2 bag record` does.
"""
from __future__ import annotations

from datetime import datetime, timezone
from pathlib import Path
import sys

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.clock import Clock, ClockType
from rclpy.node import Node

from ..bag.recorder_status import STATUS_SUFFIX, count_key
from ..bag.topics import COMMAND, DEFAULT, EVENT, LATCHED, SENSOR, TOPICS, bag_topic
from ..bag.writer import BagWriter
from ..interface import DIAGNOSTICS
from .diagnostics import publish_diagnostics, status
from .parameters import declare
from .qos import COMMAND_QOS, EVENT_QOS, LATCHED_QOS, SENSOR_QOS, deep
from .spin import run

#: A recorder must not lose what it could have buffered (offline replay pairs every step's inputs
#: with its command): the publishers' QoS with a deep history (qos.deep).
RCLPY_QOS = {SENSOR: deep(SENSOR_QOS), COMMAND: deep(COMMAND_QOS), LATCHED: deep(LATCHED_QOS),
             EVENT: deep(EVENT_QOS), DEFAULT: deep(COMMAND_QOS)}


def _message_class(ros_type: str):
    import importlib
    package, _, name = ros_type.split('/')
    return getattr(importlib.import_module(f'{package}.msg'), name)


class BagRecorder(Node):
    def __init__(self):
        super().__init__('bag_recorder')
        output = declare(self, 'output', '', "the bag folder to create (must not exist); '' = "
                         '<output_dir>/session_<UTC time>')
        output_dir = declare(self, 'output_dir', '~/.fabric_guidance/bags', 'where unnamed bags go')
        topics = declare(self, 'topics', list(TOPICS), 'topics to record (of the package\'s, see bag/topics.py)')
        period = declare(self, 'diagnostics_period_s', 0.5, 'period of the recorder\'s /diagnostics', 's', 0.05, 60.0)
        flush_period = declare(self, 'flush_period_s', 1.0, 'how often what was received goes to disk as a '
                               'complete chunk (at most this much is lost if the recorder is killed)', 's', 0.05, 60.0)
        unknown = [t for t in topics if t not in TOPICS]
        if unknown:
            raise ValueError(f'cannot record {unknown}: not topics of the package ({list(TOPICS)})')
        stamp = datetime.now(timezone.utc).strftime('%Y%m%d_%H%M%S')
        path = Path(output).expanduser() if output else Path(output_dir).expanduser() / f'session_{stamp}'
        self.bag = BagWriter(path, custom_data={'fabric_guidance.recorder': 'bag_recorder'})
        self.path = path
        self.closed = False
        for name in topics:
            ros_type, kind = TOPICS[name]
            self.bag.add_package_topic(name, self.get_namespace())
            self.create_subscription(_message_class(ros_type), name, self._writer_for(name), RCLPY_QOS[kind],
                                     raw=True)
        self.topics = list(topics)
        self.diag_pub = self.create_publisher(DiagnosticArray, DIAGNOSTICS, 10)
        # Steady clock: a recorder under use_sim_time reports before the first /clock too.
        self.create_timer(period, self.publish_diagnostics, clock=Clock(clock_type=ClockType.STEADY_TIME))
        # Same callback group as the subscriptions: a flush never runs during a write.
        self.create_timer(flush_period, self.flush, clock=Clock(clock_type=ClockType.STEADY_TIME))
        self.get_logger().info(f'recording {len(topics)} topics to {path}')

    def publish_diagnostics(self) -> None:
        if self.closed:
            return
        counts = {name: self.bag.counts.get(bag_topic(name, self.get_namespace()), 0) for name in self.topics}
        total = sum(counts.values())
        publish_diagnostics(self, self.diag_pub, [status(
            self, STATUS_SUFFIX[2:], DiagnosticStatus.OK, f'{total} messages to {self.path}',
            {'bag': str(self.path), **{count_key(name): n for name, n in counts.items()}})])

    def flush(self) -> None:
        if not self.closed:
            self.bag.flush()

    def _writer_for(self, name: str):
        topic = bag_topic(name, self.get_namespace())

        def write(data: bytes) -> None:
            if not self.closed:
                self.bag.write(topic, self.get_clock().now().nanoseconds, data)
        return write

    def safe_shutdown(self) -> None:
        if self.closed:
            return
        self.closed = True
        self.bag.close()
        counts = ', '.join(f'{t} {n}' for t, n in self.bag.counts.items())
        self.get_logger().info(f'bag written: {self.path} ({counts})')


def main(args=None) -> int:
    return run(BagRecorder, args)


if __name__ == '__main__':
    sys.exit(main())
