"""A node started by a graph (graph/process_graph.py) ends with the process that started it:
the graph names that process in PARENT_ENV, and the node asks the kernel for SIGINT when it
dies (Linux's PR_SET_PDEATHSIG). SIGINT, as Ctrl-C: the node vents and exits as on any
shutdown. A study or a test killed with SIGKILL then leaves no node behind writing into the
next run's logs or steering its domain.

The kernel ties the request to the thread that started the process: a graph started from a
thread that ends before it (not the main thread, not the graph's supervisor) would lose its
nodes with that thread.
"""
from __future__ import annotations

import os
import signal

#: The pid of the process a node is to end with (set per node by Graph.start; not inherited
#: further: a node's own children are its business).
PARENT_ENV = 'FABRIC_GUIDANCE_PARENT_PID'
PR_SET_PDEATHSIG = 1


def die_with_parent(sig: int = signal.SIGINT) -> bool:
    """Ask for `sig` when the process named in PARENT_ENV ends; False when that process has
    ended already (the caller should not start). True without the variable or off Linux."""
    text = os.environ.pop(PARENT_ENV, '')
    if not text.isdigit():
        return True
    try:
        import ctypes
        libc = ctypes.CDLL(None, use_errno=True)
        if libc.prctl(PR_SET_PDEATHSIG, int(sig), 0, 0, 0) != 0:
            return True
    except (OSError, AttributeError):
        return True
    return os.getppid() == int(text)     # after the request: a parent gone before it is seen here
