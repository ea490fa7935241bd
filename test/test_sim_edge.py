"""hololens_view.edge_deg: a wearer looking for an object keeps the goals they take from the
touch within the objects' region plus edge_deg, so a misread under Eq. 5's rising pull stops
at the region's edge instead of the seat's 120 deg; off (None) every scene runs as before."""
import numpy as np
import pytest

from fabric_guidance.sim.engine import ClosedLoop, trial_run
from fabric_guidance.sim.population import sample_wearer
from fabric_guidance.sim.scene import SceneError
from fabric_guidance.sim.wearer import SEAT_LIMITS
from test_sim_engine import NOISY, exact_cal, scene, trace

QUIET = [{'regulator_lag': {}}, {'body_dynamics': {}}]
SPEED = {'kind': 'speed'}
#: Half the reads of the cue misread its direction (the effect's largest rate).
MISREAD = {'cue_misreading': {'direction_p': 0.5, 'magnitude_sd': 0.0}}


def view(**kw):
    return {'hololens_view': kw}


def loop_for(effects, cond=1):
    sc = scene(effects, protocol=SPEED)
    w = sample_wearer(sc, 0)
    loop = ClosedLoop(sc, w, trial_run(cond, 0), cond, exact_cal(sc, w))
    loop.warm_up()
    return loop


def test_a_misread_pull_stops_at_the_objects_edge():
    # The wearers of this seed whose trial ran to the seat's limit (a misread under a pull that
    # grows while they turn away); the same wearers and draws with the edge.
    def far(edge, subject):
        gaze, _ = trace(scene(QUIET + [MISREAD, view(edge_deg=edge)], protocol=SPEED), 1,
                        target=(40.0, 0.0), seconds=8.0, subject=subject)
        return np.max(np.abs(gaze[:, 0]))
    lost = [s for s in range(6) if far(None, s) > 80.0]
    assert lost, 'no wearer of the seed ran past the objects: the test shows nothing'
    for s in lost:
        assert 55.0 < far(0.0, s) <= 60.0 + 1e-6        # at the region's edge, not beyond
        assert 60.0 < far(10.0, s) <= 70.0 + 1e-6


def test_the_edge_holds_only_while_a_visible_target_is_looked_for():
    loop = loop_for(QUIET + [view(edge_deg=10.0)])
    loop.present(40.0, 0.0, visible=True)
    assert loop.wearer.touch_limits == (70.0, 40.0)       # the paper's +-60 / +-30 plus 10
    loop.withdraw()
    assert loop.wearer.touch_limits == SEAT_LIMITS
    loop.present(40.0, 0.0, visible=False)                  # nothing to look for: the seat's limits
    assert loop.wearer.touch_limits == SEAT_LIMITS
    plain = loop_for(QUIET + [view()])
    plain.present(40.0, 0.0, visible=True)
    assert plain.wearer.touch_limits == SEAT_LIMITS


def test_an_edge_beyond_the_seat_runs_as_without_one():
    # 60 + 120 and 30 + 120 are past the seat's limits, which then decide alone: the same
    # trial, sample for sample, as a scene that does not name edge_deg.
    for cond in (1, 3):
        a, _ = trace(scene(NOISY + [MISREAD, view()], protocol=SPEED), cond, seconds=4.0)
        b, _ = trace(scene(NOISY + [MISREAD, view(edge_deg=120.0)], protocol=SPEED), cond, seconds=4.0)
        assert np.array_equal(a, b)


@pytest.mark.parametrize('edge', [-1.0, 121.0])
def test_an_edge_out_of_range_is_one_line_naming_it(edge):
    with pytest.raises(SceneError, match=r'hololens_view\.edge_deg must be') as exc:
        scene([view(edge_deg=edge)], protocol=SPEED)
    assert '\n' not in str(exc.value)
