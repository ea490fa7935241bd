"""A field missing from a scene or calibration file is named missing, not "got None" (which reads
as a null written in the file)."""
import pytest
import yaml


def test_a_missing_scene_or_coefficient_field_is_named_missing():
    """A scene without `seed` or `population.laws`, a law or a calibration without `a`: each
    read "got None", which a person takes for a null written in the file."""
    import copy
    from fabric_guidance.core.calibration import Calibration, CalibrationFileError
    from fabric_guidance.paths import config_path
    from fabric_guidance.sim.scene import SceneError, scene_from_dict
    scene = yaml.safe_load(config_path('scenes/paper-speed.yaml').read_text())
    for path in (('seed',), ('population', 'laws'), ('population', 'laws', 'left', 'a')):
        broken = copy.deepcopy(scene)
        parent = broken
        for key in path[:-1]:
            parent = parent[key]
        del parent[path[-1]]
        with pytest.raises(SceneError) as exc:
            scene_from_dict(broken, source='mine.yaml')
        assert str(exc.value).startswith(f'mine.yaml: field "{".".join(path)}" is missing'), exc.value
        assert 'None' not in str(exc.value)
    cal = yaml.safe_load(config_path('calibrations/sim-wearer.yaml').read_text())
    del cal['directions']['up']['b']
    with pytest.raises(CalibrationFileError, match='^alice.yaml: field "directions.up.b" is missing$'):
        Calibration.from_dict(cal, source='alice.yaml')
