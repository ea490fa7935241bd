"""Recording and replaying guided sessions as ROS 2 bags (rosbag2, MCAP storage) via rosbags.

controller_io  pressure_controller's step as data (controller_input layout, parameters YAML;
               the step itself is core/control_step.py); needs neither rosbags nor rclpy
topics         the recorded topics, their types and QoS (from fabric_guidance/interface.py)
writer         BagWriter: serialized messages into a rosbag2/MCAP bag with definitions and QoS
reader         the messages of a bag, raw or decoded
recovery       the intact part of an MCAP file cut off before its summary (a killed recorder)
offline        rerun the controller over recorded inputs, compare with recorded commands
player         republish recorded inputs with /clock (replay through the graph)
"""
