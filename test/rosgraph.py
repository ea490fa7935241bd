"""Test support for real ROS graphs; the launcher itself is the package's (the demo uses it too)."""
from fabric_guidance.graph.process_graph import CONFIG, ROOT, Graph, Probe, free_port, fresh_domain_id, wait_until

__all__ = ['CONFIG', 'ROOT', 'Graph', 'Probe', 'free_port', 'fresh_domain_id', 'log_tails', 'wait_until']


def log_tails(folder, lines: int = 12) -> str:
    """The last lines of every node log under `folder`: what a failed graph run said, kept in
    the failure's message (a CI machine's tmp_path is gone afterwards)."""
    from pathlib import Path
    parts = []
    for log in sorted(Path(folder).rglob('*.log')):
        tail = log.read_text(errors='replace').splitlines()[-lines:]
        parts.append(f'--- {log}\n' + '\n'.join(tail))
    return '\n'.join(parts)
