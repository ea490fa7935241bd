"""A ROS participant for the network tests, run as its own process on a host of the test
(`ip netns exec NS python netns_participant.py ...`), with whatever DDS set-up its environment
gives it. It reports what it sees of the graph, one JSON line whenever that changes:
{"m": CLOCK_MONOTONIC (the same clock as the test's), "nodes": [other nodes' names],
"subscribers": {topic: count}}, the first as soon as its node exists, where
subscribers counts the remote subscriptions matched on the topics it publishes (its own node
subscribes to none of them). With --publish pressure_command (CHANNEL at INTRUDER_KPA, the rest 0)
and/or --publish gaze it publishes there at 20 Hz, as a participant trying to drive the suit
would; a publisher the middleware refuses (SROS2 permissions) is reported as {"refused": error}
and the process exits 3. It stops by itself after --seconds. Also run outside namespaces
(test_security_policy.py).
"""
import argparse
import json
import sys
import time

import rclpy
from geometry_msgs.msg import PoseStamped
from std_msgs.msg import Float64MultiArray

from fabric_guidance import interface
from fabric_guidance.core import ChannelMap
from fabric_guidance.paths import config_path

CHANNELS = ChannelMap.load(config_path('hardware/channel_map.yaml')).channels
CHANNEL = 'F1'         # the test graph guides to the left: F1 stays at 0
INTRUDER_KPA = 123.0
TOPICS = {interface.PRESSURE_COMMAND: (Float64MultiArray, interface.COMMAND),
          interface.GAZE: (PoseStamped, interface.SENSOR)}


def main(argv=None):
    parser = argparse.ArgumentParser()
    parser.add_argument('--name', required=True)
    parser.add_argument('--seconds', type=float, required=True)
    parser.add_argument('--publish', action='append', default=[], choices=sorted(TOPICS))
    args = parser.parse_args(argv)
    rclpy.init()
    node = rclpy.create_node(args.name)
    publishers = {}
    for topic in args.publish:
        msg_type, kind = TOPICS[topic]
        try:
            publishers['/' + topic] = node.create_publisher(msg_type, topic, interface.qos_profile(kind))
        except Exception as exc:  # noqa: BLE001 - rclpy's errors have no common base; reported as they are
            print(json.dumps({'m': time.monotonic(), 'refused': f'{topic}: {exc}'}), flush=True)
            return 3
    command = Float64MultiArray(data=[INTRUDER_KPA if c == CHANNEL else 0.0 for c in CHANNELS])
    gaze = PoseStamped()
    gaze.header.frame_id = interface.IMMERSIVE_FRAME
    gaze.pose.orientation.w = 1.0
    start = time.monotonic()
    last = None
    next_publish = start
    while time.monotonic() - start < args.seconds:
        rclpy.spin_once(node, timeout_sec=0.05)
        now = time.monotonic()
        if publishers and now >= next_publish:
            gaze.header.stamp = node.get_clock().now().to_msg()
            for topic, publisher in publishers.items():
                publisher.publish(command if topic == '/' + interface.PRESSURE_COMMAND else gaze)
            next_publish = now + 0.05
        seen = {'nodes': sorted(n for n in node.get_node_names() if n != args.name),
                'subscribers': {t: p.get_subscription_count() for t, p in publishers.items()}}
        if seen != last:
            print(json.dumps({'m': now, **seen}), flush=True)
            last = seen
    node.destroy_node()
    rclpy.shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
