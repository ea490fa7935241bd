"""What the headset receives in the study's two tasks (the compiled C# decoder against the real
headset_display): in the accuracy task the target is unseen (draw_targets false: neither
drawn nor named), in the speed task it is drawn among the dummies; and the `done` event names
what ended."""
import contextlib
import socket

import pytest
from rcl_interfaces.srv import SetParameters
from rclpy.parameter import Parameter
from std_msgs.msg import String
from std_srvs.srv import Trigger

from fabric_guidance import interface
from fabric_guidance.nodes import qos
from headset_harness import Harness, build_harness
from rosgraph import Graph, Probe, free_port, wait_until

pytestmark = pytest.mark.graph

FILES = ('params/guidance.yaml',)


@pytest.fixture(scope='module', autouse=True)
def harness_built():
    build_harness()


@contextlib.contextmanager
def headset(tmp_path, **display_params):
    """target_selector and headset_display sending to the C# harness; yields (graph, harness, probe)."""
    listen = free_port(socket.SOCK_DGRAM)
    harness = Harness(tmp_path / 'harness.log', '--listen', f'127.0.0.1:{listen}', '--duration', '60', '--frames', '0')
    graph = Graph(tmp_path / 'logs')
    try:
        graph.start('target_selector', FILES, autostart=False)
        graph.start('headset_display', FILES, headset_address='127.0.0.1', display_port=listen, **display_params)
        with Probe(graph.domain_id) as probe:
            yield graph, harness, probe
        harness.stop()
    finally:
        graph.stop_all()
        harness.close()


def _next_target(probe, harness) -> str:
    active = probe.subscribe(String, interface.ACTIVE_TARGET, qos.LATCHED_QOS)
    probe.send(Trigger, interface.NEXT_TARGET, Trigger.Request())
    wait_until(lambda: any(m.data for m in active) and any(m['event'] == 'next' for m in harness.messages('event')),
               20.0, what='an active target and a next event at the headset')
    return [m.data for m in active if m.data][-1]


def test_the_accuracy_tasks_targets_are_never_drawn_nor_named(tmp_path):
    with headset(tmp_path, draw_targets=False) as (graph, harness, probe):
        name = _next_target(probe, harness)
        # a refresh (2 Hz) has gone out after the target became active
        count = len(harness.messages('targets'))
        wait_until(lambda: len(harness.messages('targets')) >= count + 2, 20.0, what='two refreshes')
        targets = harness.messages('targets')
        # none drawn: an inactive target would show where target_selector put the next one
        assert targets and all(m['active'] == '' and m['targets'] == [] for m in targets), name
        assert {m['target'] for m in harness.messages('event') if m['event'] == 'next'} == {''}
        # the speed task draws it again (set by the session before its target)
        request = SetParameters.Request(parameters=[Parameter('draw_targets', value=True).to_parameter_msg()])
        assert probe.call(SetParameters, '/headset_display/set_parameters', request).results[0].successful
        wait_until(lambda: any(m['active'] == name and any(t['id'] == name for t in m['targets'])
                               for m in harness.messages('targets')), 20.0, what=f'{name} drawn once allowed')


def test_done_names_what_ended(tmp_path):
    with headset(tmp_path) as (graph, harness, probe):
        pub = probe.node.create_publisher(String, interface.STUDY_DISPLAY, qos.EVENT_QOS)
        wait_until(lambda: pub.get_subscription_count() >= 1, 20.0, what='headset_display on study_display')
        for what in ('sequence', 'block', 'session'):
            pub.publish(String(data=f'done {what}'))
        wait_until(lambda: {m['target'] for m in harness.messages('event') if m['event'] == 'done'}
                   == {'sequence', 'block', 'session'}, 20.0, what='three done events at the headset')
        done = [m for m in harness.messages('event') if m['event'] == 'done']
        assert len({m['event_id'] for m in done}) == 3
