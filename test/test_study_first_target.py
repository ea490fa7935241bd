"""A study's lab graph (guidance.yaml with study-speed.yaml or study-accuracy.yaml) shows nothing
until the session shows its first target: no start-up target named `study` at the front, no
dummies around it during the calibration; the session's first target then gets its `next` event
like every other (before, the start-up target kept the name and trial 1 had no `next`); between
targets nothing is drawn (before, the last target stayed in view, magenta, through every rest)."""
import socket

import pytest
from rcl_interfaces.srv import SetParameters
from rclpy.parameter import Parameter

from fabric_guidance.core import display_wire
from fabric_guidance.live_study.operator import STUDY_TARGET, target_position
from rosgraph import Graph, Probe, wait_until

pytestmark = pytest.mark.graph


class Datagrams:
    """What headset_display sends, decoded (the headset's side of docs/headset_wire_format.md)."""

    def __init__(self):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(('127.0.0.1', 0))
        self.sock.settimeout(0.05)
        self.port = self.sock.getsockname()[1]
        self.messages: list = []

    def poll(self) -> list:
        try:
            while True:
                self.messages.append(display_wire.decode(self.sock.recv(65536)))
        except (socket.timeout, BlockingIOError):
            return self.messages

    def of(self, kind: str) -> list:
        return [m for m in self.poll() if m.kind == kind]


@pytest.mark.parametrize('protocol', ['speed', 'accuracy'])
def test_nothing_is_shown_before_the_sessions_first_target(tmp_path, protocol):
    files = ('params/guidance.yaml', f'params/study-{protocol}.yaml')
    udp = Datagrams()
    graph = Graph(tmp_path / 'logs')
    try:
        graph.start('target_selector', files)
        graph.start('headset_display', files, headset_address='127.0.0.1', display_port=udp.port)
        # three refreshes of the whole display state (2 Hz): what the wearer sees before the session
        wait_until(lambda: len(udp.of('targets')) >= 3, 30.0, what='three display refreshes')
        assert all(m.fields['active'] == '' for m in udp.of('targets')), udp.of('targets')
        assert not udp.of('event'), udp.of('event')
        assert all(m.fields['set'] == 0 for m in udp.of('dummies'))
        # the session's first target, as Operator.show_target places it
        with Probe(graph.domain_id) as probe:
            request = SetParameters.Request(parameters=[
                Parameter('target_positions', value=target_position(10.0, 20.0, 1.2)).to_parameter_msg(),
                Parameter('active_target', value=STUDY_TARGET).to_parameter_msg()])
            result = probe.call(SetParameters, '/target_selector/set_parameters', request)
            assert all(r.successful for r in result.results), result
        shown = STUDY_TARGET if protocol == 'speed' else ''     # the accuracy target is never named
        wait_until(lambda: any(m.fields['event'] == 'next' for m in udp.of('event')), 20.0,
                   what="the first target's next event")
        assert {m.fields['target'] for m in udp.of('event') if m.fields['event'] == 'next'} == {shown}
        if protocol == 'speed':
            wait_until(lambda: any(m.fields['set'] > 0 for m in udp.of('dummies')), 20.0,
                       what="the first target's dummies")
            assert any(m.fields['active'] == STUDY_TARGET and [t['id'] for t in m.fields['targets']] == [STUDY_TARGET]
                       for m in udp.of('targets'))
        # the rest after it, as Operator.to_front: the target stays in target_markers where it
        # was, and is not drawn (draw_inactive false): the participant sees no last target
        with Probe(graph.domain_id) as probe:
            request = SetParameters.Request(parameters=[Parameter('active_target', value='').to_parameter_msg()])
            assert probe.call(SetParameters, '/target_selector/set_parameters', request).results[0].successful
        seen = len(udp.of('targets'))
        wait_until(lambda: sum(m.fields['active'] == '' for m in udp.of('targets')[seen:]) >= 2, 20.0,
                   what='two refreshes in the rest')
        rest = [m for m in udp.of('targets')[seen:] if m.fields['active'] == '']
        assert all(m.fields['targets'] == () for m in rest), rest
    finally:
        graph.stop_all()
        udp.sock.close()
