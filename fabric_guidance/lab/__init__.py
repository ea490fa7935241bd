"""What a lab sets up around the graph, without ROS: the DDS profile of the lab network
(`dds-profile`), Fast DDS's discovery server (`discovery-server`), the SROS2 permissions policy
(`security-policy`), the operator's Foxglove layout, and a wearer's calibration report
(`calibration-report`, also written by pressure_controller after a calibration)."""
