"""The study session through the graph: an operator's client of the ROS graph (operator.py),
the protocols driven through it (live.py), the simulated study on the simulated graph
(simulated.py, session_sim.py), `fabric-guidance study` (study_command.py) and the study's timing
(timing.py, run by `fabric-guidance bench`)."""
