"""Lab nodes load only what their own job needs: each is imported in a fresh interpreter and
the heavy packages it must not pull in are looked for in sys.modules. scipy is for fits
(Algorithm 1 imports it when a calibration is fitted), matplotlib for reports, pandas and the
simulator and experiments for studies; none belongs in the processes that run beside a wearer."""
import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
#: Nodes that run in a lab session; the simulators (mock_plc, wearer_sim, micromanipulator_sim)
#: stand in for hardware and people and may load what they like.
SIMULATORS = {'mock_plc', 'wearer_sim', 'micromanipulator_sim'}
HEAVY = ('scipy', 'matplotlib', 'pandas', 'fabric_guidance.sim', 'fabric_guidance.experiments',
         'fabric_guidance.bench', 'hypothesis')
#: What a node's job does need, beyond rclpy and numpy.
NEEDS = {'bag_recorder': ('rosbags',)}


def lab_nodes():
    text = (ROOT / 'setup.py').read_text()
    found = re.findall(r"'(\w+) = fabric_guidance\.nodes\.(\w+):main'", text)
    return sorted(module for name, module in found if name not in SIMULATORS)


def test_the_lab_nodes_are_the_ones_launched():
    launch = (ROOT / 'launch' / 'guidance.launch.py').read_text()
    listed = set(re.search(r'NODES = \(([^)]*)\)', launch).group(1).replace("'", '').replace(' ', '').split(','))
    assert listed <= set(lab_nodes())


@pytest.mark.parametrize('module', lab_nodes())
def test_a_lab_node_imports_no_heavy_package(module):
    code = ('import json, sys; import fabric_guidance.nodes.%s; '
            'print(json.dumps(sorted(m for m in sys.modules)))' % module)
    loaded = set(json.loads(subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                                           check=True, timeout=120).stdout))
    heavy = sorted(h for h in HEAVY if h in loaded)
    assert not heavy, f'fabric_guidance.nodes.{module} loads {heavy} (see this module\'s doc)'
    for needed in NEEDS.get(module, ()):
        assert needed in loaded, needed   # the test sees real imports, not an empty list


def test_micromanipulation_launch_passes_every_argument_of_the_lab_launch():
    """docs/launch.md says micromanipulation.launch.py takes every argument of guidance.launch.py;
    it declared neither `wearer` nor `study`. Read from the files' text (no launch package here)."""
    import ast
    guidance = ast.parse((ROOT / 'launch' / 'guidance.launch.py').read_text())
    micro = ast.parse((ROOT / 'launch' / 'micromanipulation.launch.py').read_text())

    def assigned(tree, name):
        return next(node.value for node in tree.body if isinstance(node, ast.Assign)
                    and any(isinstance(t, ast.Name) and t.id == name for t in node.targets))
    table = {key.value for key in assigned(guidance, 'ARGUMENTS').keys}
    declared = {node.args[0].value for node in ast.walk(guidance) if isinstance(node, ast.Call)
                and getattr(node.func, 'id', '') == 'DeclareLaunchArgument' and isinstance(node.args[0], ast.Constant)}
    helpers = {'study', 'respawn', 'respawn_delay', 'keystore', 'discovery_server', 'start_discovery_server'}
    passed = set(ast.literal_eval(assigned(micro, 'PASS_THROUGH')))
    own = {'params_file', 'extra_params_file'}   # micromanipulation's base_params_file, its own file
    assert {'wearer', 'condition', 'plc_host'} <= table
    assert (table | declared | helpers) - own <= passed, sorted((table | declared | helpers) - own - passed)
