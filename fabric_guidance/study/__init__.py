"""A live study with people: the plan of a participant's blocks and trials (plan.py), the
session as a state machine driven by timestamped events (session.py) and the study folder a
session writes as it goes (store.py). No ROS here: the operator node drives a Session with
the graph's events and carries out the actions it returns (docs/study.md).
"""
