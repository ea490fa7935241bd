"""A node's main loop: spin until SIGINT or SIGTERM, then run the node's safe shutdown (vent)
while the ROS context is still up, and bound the teardown after it.

Nodes stay thin: they parse parameters, wire topics and services, and call the core.
"""
from __future__ import annotations

import faulthandler
import gc
import os
import signal
import sys
import threading
from typing import Callable, Sequence

import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions

from . import exit_timer
from .managed import ConfigureError, ManagedNode
from .parent import die_with_parent
from .parameters import check_params_files


#: Once a node has vented, its teardown (destroying the node, the ROS context, the interpreter's
#: exit) gets this long before the process ends itself [s]; `ros2 launch` escalates after 5 s.
TEARDOWN_LIMIT_S = 2.0
#: ... and if the timer that ends it cannot run (it needs the GIL, which a call into C may hold
#: while it waits: Fast DDS deadlocking in an entity's deletion), faulthandler's watchdog, a C
#: thread, writes every thread's stack to stderr (the node's log) this much later [s] ...
TEARDOWN_BACKSTOP_S = 1.5
#: ... and a C library timer (nodes/exit_timer.py) ends the process this much after that, with the
#: status the node would have had: the vent was done, a hung teardown is not the node's failure [s].
STACKS_WRITE_S = 0.25


def _end_process(code: int) -> None:
    """Ends the process now: the vent is done, whatever holds the teardown is not worth waiting
    for (a non-daemon thread, a DDS entity's destruction)."""
    try:
        sys.stdout.flush()
        sys.stderr.flush()
    finally:
        os._exit(code)


#: The executor the nodes spin in: 'events' (rclpy's EventsExecutor, rclpy.experimental in
#: Kilted; the default) or 'single' (rclpy's SingleThreadedExecutor). Measured on the package
#: graph (docs/benchmarks.md): the events executor halves pressure_controller's and plc_output's
#: CPU per gaze sample and takes 0.9 ms off the 90 Hz median; 'single' is the fallback should
#: the experimental executor misbehave on a lab's rclpy.
EXECUTOR_ENV = 'FABRIC_GUIDANCE_EXECUTOR'
DEFAULT_EXECUTOR = 'events'


def make_executor(kind: str = DEFAULT_EXECUTOR):
    """The executor of `kind`, unless the environment variable names one for every node."""
    kind = os.environ.get(EXECUTOR_ENV, kind)
    if kind == 'events':
        try:
            from rclpy.experimental import EventsExecutor
        except ImportError:          # an rclpy before Kilted: the one executor it has
            return SingleThreadedExecutor()
        return EventsExecutor()
    if kind != 'single':
        raise ValueError(f'{EXECUTOR_ENV}={kind!r}: use single or events')
    return SingleThreadedExecutor()


class StopRequest:
    """The SIGINT / SIGTERM handler: a plain attribute, no lock. A second signal can arrive while
    the handler runs (Ctrl-C twice, a launch's SIGINT then SIGTERM, the parent-death SIGINT beside
    a graph's SIGTERM) and Python runs its handler inside the first one: a handler that takes a
    lock, as threading.Event.set does, then waits for itself, and the node never vents (seen: a
    controller hung so in its start-up, listed on the graph for minutes after its test)."""

    def __init__(self) -> None:
        self.requested = False

    def __call__(self, signum, frame) -> None:
        self.requested = True


def run(make_node: Callable[[], Node], args: Sequence[str] | None = None, executor: str = DEFAULT_EXECUTOR) -> int:
    """Spin a node until SIGINT or SIGTERM, then call its `safe_shutdown()` (vent) while the
    ROS context is still up so that it can still publish or write, and exit 0.

    rclpy's own signal handlers would shut the context down first; ours only set a flag that
    the spin loop checks every 50 ms. Raising from the handler instead would interrupt whatever
    runs at that instant (a callback, rclpy's C++ take path, a Modbus request) half-way.
    A node a graph started ends with the graph's process (nodes/parent.py).
    """
    if not die_with_parent():
        print('[fabric_guidance] not started: the process that started this node has ended', flush=True)
        return 1
    try:
        check_params_files(sys.argv if args is None else args)
        rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    except Exception as exc:  # a bad command line or parameters file: no context, no node yet
        print(f'[fabric_guidance] cannot start: {" ".join(str(exc).split())[:300]}', flush=True)
        return 1
    stop = StopRequest()
    signal.signal(signal.SIGINT, stop)
    signal.signal(signal.SIGTERM, stop)
    node = spinner = None
    code = 0
    try:
        node = make_node()
        if isinstance(node, ManagedNode):
            node.start_up()     # autostart: configure and activate (ConfigureError: cannot start)
        # Everything built so far (modules, the node) lives as long as the process: keep it out
        # of the collector's full passes, which would otherwise walk it all (milliseconds, in the
        # middle of a control step) every so many allocations.
        gc.collect()
        gc.freeze()
        spinner = make_executor(executor)
        spinner.add_node(node)
        while not stop.requested and rclpy.ok():
            spinner.spin_once(timeout_sec=0.05)
    except ExternalShutdownException:
        pass
    except ConfigureError as exc:   # the node's error line is logged; this is the process's
        print(f'[fabric_guidance] cannot start: {exc}', flush=True)
        code = 1
    except Exception as exc:  # a start-up error (bad parameter or file) ends with its message
        if node is None:
            print(f'[fabric_guidance] cannot start: {" ".join(str(exc).split())[:300]}', flush=True)
            code = 1
        else:
            raise
    finally:
        # Ignore further signals while venting: a second Ctrl-C must not skip it.
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        if node is not None:
            safe_shutdown = getattr(node, 'safe_shutdown', None)
            if safe_shutdown is not None:
                safe_shutdown()
        # From here on nothing is left to do that matters to the suit: bound the rest.
        failing = sys.exc_info()[0] is not None  # an error on its way out: exit 1, not 0
        status = 1 if failing else code
        limit = threading.Timer(TEARDOWN_LIMIT_S, _end_process, args=(status,))
        limit.daemon = True
        limit.start()
        # Should the teardown hold the GIL (headset_display outlived SIGINT and SIGTERM by 15 s in a
        # launch test; wearer_sim hung in destroy_node in CI), the stacks say where and it still
        # ends, with its own status where the C library can (else faulthandler's status 1).
        backstop = TEARDOWN_LIMIT_S + TEARDOWN_BACKSTOP_S
        armed = exit_timer.arm(backstop + STACKS_WRITE_S, status)
        faulthandler.dump_traceback_later(backstop, exit=not armed)
        # rclpy's order: the executor lets go of the node's entities while the node and the context
        # stand. Left to the events executor's destructor at this function's end, an entity's
        # release came after both were gone and once hung there holding the GIL (wearer_sim, in
        # an event handler's __exit__, ended by the backstop with status 1: fresh run 115).
        if spinner is not None:
            spinner.shutdown()
        if node is not None:
            node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()
    return code
