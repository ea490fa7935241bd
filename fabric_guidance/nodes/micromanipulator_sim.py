"""micromanipulator_sim: a simulated micromanipulation stack for the paper's demonstration.

Publishes the poses of the objects under the microscope, a holding pipette, a microbead and an
injection pipette by default, as geometry_msgs/PoseStamped in the `microscope` frame, in
metres at micro scale (1 mm = 0.001), each on <topic_prefix>/<name>. With the default prefix
`live_targets` the topics are the ones target_selector's live targets listen to, so the
simulator plugs straight in; a real stack's topics are remapped onto them instead
(launch/micromanipulation.launch.py).

The microscope frame here has its axes parallel to the immersive frame (REP 103: x away from
the wearer, y to the wearer's left, z up) and its origin at the centre of the field of view:
target_selector maps a position only by position * live_scale + live_offset, no rotation.
The orientation is the identity (target_selector uses positions only).

With drift_amplitude_m > 0 every object drifts slowly on a circle in the focal (x-y) plane,
drift_period_s per turn, each object a third of a turn after the previous one: the stage and
the pipettes of a real setup are never perfectly still, and the live targets must follow.

Publishes   <topic_prefix>/<name> (PoseStamped, frame frame_id, m) for each of object_names
"""
from __future__ import annotations

import math
import sys

from geometry_msgs.msg import PoseStamped
from rclpy.clock import Clock, ClockType
from rclpy.node import Node

from ..interface import LIVE_TARGETS
from .parameters import declare
from .qos import SENSOR_QOS
from .spin import run

#: The paper's demonstration objects, in the order the wearer is guided to them.
DEFAULT_NAMES = ['holding_pipette', 'microbead', 'injection_pipette']
#: Tip positions in the microscope frame, metres: the holding pipette comes in from the left
#: and the injection pipette from the right, the bead between them, a little below focus.
DEFAULT_POSITIONS = [0.0, 1.0e-3, 0.0,
                     0.0, 0.6e-3, -0.25e-3,
                     0.0, -1.0e-3, 0.05e-3]
MICROSCOPE_FRAME = 'microscope'


class MicromanipulatorSim(Node):

    def __init__(self):
        super().__init__('micromanipulator_sim')
        self.frame_id = declare(self, 'frame_id', MICROSCOPE_FRAME, 'frame of the published poses', read_only=True)
        names = declare(self, 'object_names', DEFAULT_NAMES, 'objects under the microscope, one topic each',
                        read_only=True)
        positions = declare(self, 'object_positions', DEFAULT_POSITIONS,
                            'x, y, z of each object in the microscope frame, in object_names order', 'm',
                            read_only=True)
        self.prefix = declare(self, 'topic_prefix', LIVE_TARGETS, 'poses go to <topic_prefix>/<name>',
                              read_only=True)
        rate = declare(self, 'publish_rate_hz', 30.0, 'poses per second per object', 'Hz', 0.1, 1000.0,
                       read_only=True)
        self.drift_amplitude = declare(self, 'drift_amplitude_m', 0.0, 'radius of the slow drift of every '
                                       'object in the focal plane (0: still)', 'm', 0.0, 1e-2, read_only=True)
        self.drift_period = declare(self, 'drift_period_s', 60.0, 'time for one turn of the drift', 's',
                                    0.1, 3600.0, read_only=True)
        names = [n for n in (names or []) if n != '']
        positions = list(positions or [])
        if not names:
            raise ValueError("parameter 'object_names': no object")
        if len(set(names)) != len(names):
            raise ValueError(f"parameter 'object_names': duplicate names in {names}")
        bad = [n for n in names if not (n.replace('_', 'a').isalnum() and n.isascii() and not n[0].isdigit())]
        if bad:
            raise ValueError(f"parameter 'object_names': {bad} are not valid topic name parts "
                             '(letters, digits and _, not starting with a digit)')
        if len(positions) != 3 * len(names) or not all(math.isfinite(v) for v in positions):
            raise ValueError(f"parameter 'object_positions': needs 3 finite values (x, y, z) per name of "
                             f"'object_names', i.e. {3 * len(names)}, got {positions}")
        self.objects = {n: tuple(positions[3 * i:3 * i + 3]) for i, n in enumerate(names)}
        self.pubs = {n: self.create_publisher(PoseStamped, f'{self.prefix}/{n}', SENSOR_QOS) for n in names}
        self.steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.start = self.steady.now().nanoseconds * 1e-9
        self.create_timer(1.0 / rate, self.publish, clock=self.steady)
        self.get_logger().info(
            f'{len(names)} objects in frame {self.frame_id!r} on {self.prefix}/<name>: '
            + ', '.join(f'{n} ({", ".join(f"{1e3 * v:+.3f}" for v in p)}) mm' for n, p in self.objects.items())
            + (f'; drifting {1e6 * self.drift_amplitude:g} um per {self.drift_period:g} s'
               if self.drift_amplitude > 0 else ''))

    def position(self, index: int, base: tuple[float, float, float], t: float) -> tuple[float, float, float]:
        """Where object `index` is t seconds after start-up: base plus the drift."""
        if self.drift_amplitude <= 0:
            return base
        phase = 2 * math.pi * (t / self.drift_period + index / 3.0)
        return (base[0] + self.drift_amplitude * math.cos(phase), base[1] + self.drift_amplitude * math.sin(phase),
                base[2])

    def publish(self) -> None:
        t = self.steady.now().nanoseconds * 1e-9 - self.start
        stamp = self.get_clock().now().to_msg()
        for i, (name, base) in enumerate(self.objects.items()):
            msg = PoseStamped()
            msg.header.stamp = stamp
            msg.header.frame_id = self.frame_id
            msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = self.position(i, base, t)
            msg.pose.orientation.w = 1.0
            self.pubs[name].publish(msg)


def main(args=None) -> int:
    return run(MicromanipulatorSim, args)


if __name__ == '__main__':
    sys.exit(main())
