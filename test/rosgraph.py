"""Test support for real ROS graphs; the launcher itself is the package's (the demo uses it too)."""
from fabric_guidance.graph.process_graph import CONFIG, ROOT, Graph, Probe, free_port, fresh_domain_id, wait_until

__all__ = ['CONFIG', 'ROOT', 'Graph', 'Probe', 'free_port', 'fresh_domain_id', 'wait_until']
