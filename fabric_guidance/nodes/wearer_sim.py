"""wearer_sim: a simulated wearer in the loop, sending gaze the way the HoloLens does.

It feels the regulators' measured pressures (measured_pressure, from the PLC), turns torso and
gaze by fabric_guidance.sim.wearer.SimulatedWearer, and sends gaze datagrams (wire format v1,
Unity frame) over UDP to gaze_bridge. With return_to_front it turns back to the front while
no target is active, as the paper's wearers did between targets.

Subscribes  measured_pressure (Float64MultiArray, kPa), active_target (String)
Sends       UDP gaze datagrams to bridge_host:bridge_port
"""
from __future__ import annotations

import socket
import sys
import time

import numpy as np
from rclpy.node import Node
from std_msgs.msg import Float64MultiArray, String

from ..core import ChannelMap, PowerLaw, ray_orientation
from ..core.gaze_wire import encode_datagram, ros_to_unity_point, ros_to_unity_quaternion
from ..paths import resolve
from ..sim.wearer import SimulatedWearer
from .common import ACTIVE_TARGET, COMMAND_QOS, LATCHED_QOS, MEASURED_PRESSURE, declare, run

#: Measured pressures older than this are not felt any more (the PLC link is gone) [s].
PRESSURE_TIMEOUT_S = 0.5


class WearerSim(Node):
    def __init__(self):
        super().__init__('wearer_sim')
        self.address = (declare(self, 'bridge_host', '127.0.0.1', 'where gaze_bridge listens'),
                        declare(self, 'bridge_port', 5005, 'gaze_bridge UDP port', low=1, high=65535))
        rate = declare(self, 'gaze_rate_hz', 60.0, 'gaze datagrams per second', 'Hz', low=1.0, high=2000.0)
        tau = declare(self, 'tau_s', 0.4, 'torso/gaze time constant', 's', low=0.01, high=10.0)
        self.layout = declare(self, 'layout', 'suit', 'which channels the wearer feels: suit or arm')
        laws = declare(self, 'laws', [20.0, 0.65, 25.0, 22.0, 0.62, 20.0, 40.0, 0.55, 30.0, 38.0, 0.58, 35.0],
                       "the wearer's own power law a, b, c per direction (left, right, down, up)")
        self.eye_height = declare(self, 'eye_height_m', 1.2, 'gaze origin above the immersive origin', 'm',
                                  low=0.0, high=3.0)
        self.return_to_front = declare(self, 'return_to_front', True,
                                       'turn back to the front while no target is active (the speed protocol)')
        channel_map_file = declare(self, 'channel_map_file', '', "channel map (YAML); '' = the package's")
        if len(laws) != 12:
            raise ValueError(f'parameter laws needs 12 numbers (a, b, c for 4 directions), got {len(laws)}')
        self.channel_map = ChannelMap.load(resolve(channel_map_file, 'channel_map.yaml'))
        self.channel_map.to_directions(np.zeros(len(self.channel_map.channels)), self.layout)  # validates layout
        self.wearer = SimulatedWearer([PowerLaw(*laws[i:i + 3]) for i in range(0, 12, 3)], tau_s=tau)
        self.pressures = np.zeros(4)
        self.pressures_received = -float('inf')
        self.active = ''
        self.seq = 0
        self.last_step = time.monotonic()
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.create_subscription(Float64MultiArray, MEASURED_PRESSURE, self.on_pressure, COMMAND_QOS)
        self.create_subscription(String, ACTIVE_TARGET, self.on_active_target, LATCHED_QOS)
        self.create_timer(1.0 / rate, self.step)

    def on_pressure(self, msg: Float64MultiArray) -> None:
        if len(msg.data) != len(self.channel_map.channels):
            return
        self.pressures = self.channel_map.to_directions(np.nan_to_num(np.asarray(msg.data)), self.layout)
        self.pressures_received = time.monotonic()

    def on_active_target(self, msg: String) -> None:
        self.active = msg.data

    def step(self) -> None:
        now = time.monotonic()
        dt, self.last_step = now - self.last_step, now
        if self.return_to_front and not self.active:
            gaze = self.wearer.return_to_front(dt)
        else:
            felt = self.pressures if now - self.pressures_received <= PRESSURE_TIMEOUT_S else np.zeros(4)
            gaze = self.wearer.step(felt, dt)
        head = ros_to_unity_quaternion(ray_orientation(gaze))
        origin = (0.0, self.eye_height, 0.0)   # Unity: y up
        datagram = encode_datagram(self.seq, now, origin, ros_to_unity_point(gaze), origin, head, True)
        self.seq = (self.seq + 1) % 2 ** 32
        try:
            self.sock.sendto(datagram, self.address)
        except OSError as exc:  # the bridge not there yet is no reason to stop
            self.get_logger().warn(f'cannot send gaze: {exc}', throttle_duration_sec=5.0)

    def safe_shutdown(self) -> None:
        self.sock.close()


def main(args=None) -> int:
    return run(WearerSim, args)


if __name__ == '__main__':
    sys.exit(main())
