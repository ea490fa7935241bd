"""Benchmarks: the loop from gaze to regulator against the floor of its transports, the core's
component costs, memory per node and simulation/replay throughput (`fabric-guidance bench`).

- gaze_sweep: a gaze sweep whose every sample lands as its own register value
- latency:    the sender, the mock PLC's write log, matching sample to landing
- floor:      the bare chain (UDP, DDS hops, one Modbus write) as separate processes
- graphs:     the package's graph and the floor's, started and measured
- components: controller step, datagram parse, calibration fit
- throughput: headless simulation and offline replay speed
- headset:    capture to register with the compiled C# headset as the source
- memory:     resident memory of every lab node beside a bare rclpy node
- runner:     everything in order, bench/results.json and bench/results.md
- faultproxy: a TCP proxy that drops, delays, holds or cuts the Modbus link at run time
- chaos:      a seeded schedule of faults on the lab graph, held to the PLC register log's
              invariants (`fabric-guidance chaos`)
- soak:       the simulated graph guiding for N minutes, a row of figures per minute
              (`fabric-guidance soak`)
- soak_report: the soak's verdict on drift, its summary and its plot
"""
