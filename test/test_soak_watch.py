"""The soak's watch counts the control steps the graph lost, not those its own process was too
busy to take: a stall of the watch's thread longer than a reader of depth 10 covers loses no step
(fresh run 110: 3 steps unseen in a quiet soak row)."""
import time

import pytest
from std_msgs.msg import Float64MultiArray

from fabric_guidance import interface
from fabric_guidance.bag.controller_io import INPUT_SIZE, STEP
from fabric_guidance.bench.soak_latency import LatencyMatcher
from fabric_guidance.bench.soak_watch import SoakWatch
from fabric_guidance.nodes import qos
from rosgraph import Probe, fresh_domain_id, wait_until

pytestmark = pytest.mark.timing   # waits on DDS in this process (make flakes runs it)

STEPS = 300


def test_a_stalled_watch_sees_every_control_step_once_it_runs_again():
    domain = fresh_domain_id()
    with Probe(domain, 'soak_watch') as watching, Probe(domain, 'pressure_controller') as controller:
        matcher = LatencyMatcher(lambda kpa: [0] * len(kpa), ())
        SoakWatch(watching, matcher)
        pub = controller.node.create_publisher(Float64MultiArray, interface.CONTROLLER_INPUT, qos.COMMAND_QOS)
        # Both sides: a volatile reader that matches the writer after a sample was sent never gets
        # it, and a lost first step is not a gap (fresh run 131: 288 of 300, none unseen).
        topic = watching.node.resolve_topic_name(interface.CONTROLLER_INPUT)
        sub = next(s for s in watching.node.subscriptions if s.topic_name == topic)
        wait_until(lambda: pub.get_subscription_count() >= 1 and sub.get_publisher_count() >= 1, 30,
                   what='the watch and the controller matched on controller_input, both ways')
        msg = Float64MultiArray(data=[0.0] * INPUT_SIZE)
        # The matcher's lock held: the watch's thread stops in its first on_input, as under a
        # long GIL hold or a busy core, while 300 steps (30 depths of 10) are published.
        with matcher._lock:
            for step in range(STEPS):
                msg.data[STEP] = float(step)
                pub.publish(msg)
                time.sleep(0.005)
        wait_until(lambda: matcher._last_step == STEPS - 1, 30, what=f'step {STEPS - 1} at the watch')
        assert (matcher.counts['steps'], matcher.counts['steps_unseen']) == (STEPS, 0)
