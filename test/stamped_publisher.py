"""A node named pressure_controller that publishes one command at 20 Hz for a while: run under
faketime by test_plc_stop.py, so that its source timestamps lie in the future of the host's
clock (a clock stepped back at the receiver looks the same).

    python stamped_publisher.py DOMAIN_ID KPA DURATION_S
"""
import sys
import time

import rclpy
from std_msgs.msg import Float64MultiArray

from fabric_guidance.core.channels import ChannelMap
from fabric_guidance.interface import PRESSURE_COMMAND
from fabric_guidance.nodes.array_layout import named_layout
from fabric_guidance.nodes.qos import COMMAND_QOS
from fabric_guidance.paths import config_path


def main():
    domain_id, kpa, duration_s = int(sys.argv[1]), float(sys.argv[2]), float(sys.argv[3])
    channels = ChannelMap.load(config_path('hardware/channel_map.yaml')).channels
    rclpy.init(domain_id=domain_id)
    node = rclpy.create_node('pressure_controller')
    pub = node.create_publisher(Float64MultiArray, PRESSURE_COMMAND, COMMAND_QOS)
    msg = Float64MultiArray(layout=named_layout(channels), data=[kpa] * len(channels))
    end = time.monotonic() + duration_s
    while time.monotonic() < end:
        pub.publish(msg)
        time.sleep(0.05)
    node.destroy_node()
    rclpy.shutdown()


if __name__ == '__main__':
    main()
