"""The floor: the package's chain with no package logic, as separate processes.

  udp     receives the datagram (8 bytes: sample, register count) and publishes a PoseStamped
          carrying the count (the gaze hop; sensor-data QoS, as `gaze`)
  relay   takes it and publishes a Float64MultiArray of 18 values (the command hop; reliable
          depth 10, as `pressure_command`)
  modbus  writes the 18 values as register counts in one Modbus TCP request (PlcClient.write_counts)

Each hop is what the package's path cannot avoid: a UDP receive, a DDS publish and subscribe
per node hop, one Modbus write, in Python on rclpy, spun as the package's nodes spin
(nodes/spin.run: the executor of the node each hop stands for, spin_once with a 50 ms timeout).

    python -m fabric_guidance.bench.floor udp --port P | relay | modbus --plc-port P
"""
from __future__ import annotations

import argparse
import signal
import socket
import struct
import sys
import threading

DATAGRAM = struct.Struct('<Iq')   # sample number, register count
GAZE_TOPIC, COMMAND_TOPIC = 'floor_gaze', 'floor_command'
N_CHANNELS, CHANNEL_INDEX = 18, 8   # L1


def encode(i: int, count: int) -> bytes:
    return DATAGRAM.pack(i, count)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument('role', choices=('udp', 'relay', 'modbus'))
    parser.add_argument('--port', type=int, default=0, help='udp: port to listen on')
    parser.add_argument('--plc-port', type=int, default=1502, help='modbus: the mock PLC')
    args, _ = parser.parse_known_args(argv)

    import rclpy
    from rclpy.signals import SignalHandlerOptions
    from geometry_msgs.msg import PoseStamped
    from std_msgs.msg import Float64MultiArray
    from ..nodes.qos import COMMAND_QOS, SENSOR_QOS

    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    stop = threading.Event()
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    node = rclpy.create_node(f'floor_{args.role}')
    closers = []

    if args.role == 'udp':
        pub = node.create_publisher(PoseStamped, GAZE_TOPIC, SENSOR_QOS)
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.bind(('127.0.0.1', args.port))
        sock.settimeout(0.1)

        def receive():
            while not stop.is_set():
                try:
                    data = sock.recv(64)
                except socket.timeout:
                    continue
                msg = PoseStamped()
                msg.pose.position.x = float(DATAGRAM.unpack_from(data)[1])
                pub.publish(msg)
        thread = threading.Thread(target=receive, daemon=True)
        thread.start()
        closers.append(lambda: (thread.join(1.0), sock.close()))
    elif args.role == 'relay':
        pub = node.create_publisher(Float64MultiArray, COMMAND_TOPIC, COMMAND_QOS)
        values = [0.0] * N_CHANNELS

        def relay(msg):
            values[CHANNEL_INDEX] = msg.pose.position.x
            pub.publish(Float64MultiArray(data=values))
        node.create_subscription(PoseStamped, GAZE_TOPIC, relay, SENSOR_QOS)
    else:
        from ..paths import config_path
        from ..plc import PlcClient, PlcLinkError, RegisterMap
        client = PlcClient(RegisterMap.load(config_path('hardware/plc_register_map.yaml')), '127.0.0.1', args.plc_port,
                           timeout_s=0.5)
        client.connect()

        def write(msg):
            try:
                client.write_counts([int(v) for v in msg.data])
            except PlcLinkError as exc:
                print(f'floor modbus: {exc}', flush=True)
        node.create_subscription(Float64MultiArray, COMMAND_TOPIC, write, COMMAND_QOS)
        closers.append(client.close)

    from ..nodes.spin import DEFAULT_EXECUTOR, make_executor
    # Each hop spun as the node it stands for (like compared with like): the Modbus writer as
    # plc_output (single-threaded), the others as gaze_bridge and pressure_controller.
    executor = make_executor('single' if args.role not in ('udp', 'relay') else DEFAULT_EXECUTOR)
    executor.add_node(node)
    try:
        while not stop.is_set() and rclpy.ok():
            executor.spin_once(timeout_sec=0.05)
    finally:
        stop.set()
        for close in closers:
            close()
        executor.shutdown()
        node.destroy_node()
        rclpy.shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
