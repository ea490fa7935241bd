"""headset_display in this process, its datagrams received on a UDP socket of the test and read
as the headset reads them (display_wire.DisplayView, the twin of the C# DisplayState): event
copies against the seq rule when other messages go out between them; the speed task's dummies
seen from the eye. The test thread calls the node's callbacks and spins its timers itself, so
what is sent between two copies is the test's doing, not a race."""
import contextlib
import socket
import time

import pytest
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from std_msgs.msg import String

from fabric_guidance.core import display_wire as dw
from fabric_guidance.graph.process_graph import fresh_domain_id
from fabric_guidance.nodes.headset_display import EVENT_SENDS, HeadsetDisplay

pytestmark = pytest.mark.timing


class Rig:
    """The node, its executor and the socket its datagrams arrive on."""

    def __init__(self, node, executor, sock):
        self.node, self.executor, self.sock = node, executor, sock
        self.received: list[dw.DisplayMessage] = []

    def drain(self) -> None:
        while True:
            try:
                self.received.append(dw.decode(self.sock.recv(2048)))
            except BlockingIOError:
                return

    def spin_until(self, predicate, timeout: float, what: str, each=lambda: None) -> None:
        """Run `each`, spin the node once and read what arrived, until predicate() or the deadline."""
        deadline = time.monotonic() + timeout
        while True:
            each()
            self.executor.spin_once(timeout_sec=0.005)
            self.drain()
            if predicate():
                return
            if time.monotonic() > deadline:
                raise AssertionError(f'timed out after {timeout:.1f} s waiting for {what}')


@contextlib.contextmanager
def display_node(**params):
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(('127.0.0.1', 0))
    sock.setblocking(False)
    context = Context()
    rclpy.init(context=context, domain_id=fresh_domain_id())
    values = {'headset_address': '127.0.0.1', 'display_port': sock.getsockname()[1], **params}
    node = executor = None
    try:
        node = HeadsetDisplay(context=context, parameter_overrides=[Parameter(k, value=v) for k, v in values.items()])
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)
        yield Rig(node, executor, sock)
    finally:
        if executor is not None:
            executor.shutdown()
        if node is not None:
            node.destroy_node()
        rclpy.shutdown(context=context)
        sock.close()


def shown(msgs, order=None) -> list[str]:
    """What a headset receiving `msgs` (in `order`, indices) newly shows, line by line."""
    view = dw.DisplayView()
    return [line for i in (range(len(msgs)) if order is None else order) for line in view.apply(msgs[i])]


# --- events: repeats and the seq rule ---------------------------------------------------------

def test_event_copies_sent_among_other_messages_are_never_stale_and_repair_a_lost_first_copy():
    with display_node(refresh_hz=50.0) as rig:
        rig.node.on_study(String(data='found t1'))
        prompts = iter(range(10 ** 6))
        # a new prompt before every spin: whatever the timers send, prompts go out between copies
        rig.spin_until(lambda: sum(m.kind == 'event' for m in rig.received) >= EVENT_SENDS, 10.0,
                       what=f'{EVENT_SENDS} copies of the event',
                       each=lambda: rig.node.on_study(String(data=f'prompt step {next(prompts)}')))
    msgs = rig.received
    copies = [i for i, m in enumerate(msgs) if m.kind == 'event']
    assert len(copies) == EVENT_SENDS and len({msgs[i].fields['event_id'] for i in copies}) == 1
    # the case in question: other messages sent after the first copy, before the others
    assert any(m.kind != 'event' for m in msgs[copies[0]:copies[-1]]), [m.kind for m in msgs]
    # (a) in the order sent, no copy is stale: each is ahead of everything sent before it
    view = dw.DisplayView()
    stale = []
    for i, m in enumerate(msgs):
        before = view.stale
        view.apply(m)
        if view.stale > before:
            stale.append((i, m.kind, m.seq))
    assert stale == [], f'stale: {stale}'
    assert shown(msgs).count('found t1') == 1
    # (b) the first copy lost: a later copy shows the event, once
    assert shown(msgs, [i for i in range(len(msgs)) if i != copies[0]]).count('found t1') == 1
    # (c) reordered by the network: any two neighbours swapped, or the first copy arriving last
    # (stale then): the event is shown once
    orders = [list(range(len(msgs)))]
    for i in range(len(msgs) - 1):
        order = list(range(len(msgs)))
        order[i], order[i + 1] = order[i + 1], order[i]
        orders.append(order)
    orders.append([i for i in range(len(msgs)) if i != copies[0]] + [copies[0]])
    for order in orders:
        assert shown(msgs, order).count('found t1') == 1, order
