"""package.xml declares every import of the package, its launch files and its tests, so that
`rosdep install` + `colcon build` gives a workspace in which every command starts and `colcon
test` collects. The imports are read from the source (function-level imports and
pytest.importorskip included); each third-party module maps to the rosdep key that installs it
on Ubuntu 24.04 for ROS 2 Jazzy and Kilted (the keys were checked against ros/rosdistro's
rosdep/python.yaml and jazzy/ and kilted/distribution.yaml: docs/launch.md, "Dependencies").
A new import fails here until it has a key in MODULE_KEYS and in package.xml; a key nothing
imports any more fails too.
"""
import ast
from pathlib import Path
import sys
import xml.etree.ElementTree as ET

ROOT = Path(__file__).resolve().parent.parent

#: import name -> rosdep key. ROS packages are their own keys (jazzy/ and kilted/distribution.yaml);
#: python3-* keys are rosdep/python.yaml's (apt on noble, or pip where the key ends in -pip).
MODULE_KEYS = {
    'rclpy': 'rclpy', 'rcl_interfaces': 'rcl_interfaces', 'lifecycle_msgs': 'lifecycle_msgs',
    'rosgraph_msgs': 'rosgraph_msgs', 'std_msgs': 'std_msgs', 'std_srvs': 'std_srvs',
    'geometry_msgs': 'geometry_msgs', 'diagnostic_msgs': 'diagnostic_msgs',
    'visualization_msgs': 'visualization_msgs', 'launch': 'launch', 'launch_ros': 'launch_ros',
    'ament_index_python': 'ament_index_python',
    'numpy': 'python3-numpy', 'scipy': 'python3-scipy', 'pymodbus': 'python3-pymodbus',
    'transforms3d': 'python3-transforms3d', 'yaml': 'python3-yaml', 'matplotlib': 'python3-matplotlib',
    'pandas': 'python3-pandas',
    'rosbags': 'python3-rosbags-pip',
    # The mcap library has no key of its own: mcap-ros2-support (pip) requires it.
    'mcap': 'mcap-ros2-support', 'mcap_ros2': 'mcap-ros2-support',
    # tests
    'pytest': 'python3-pytest', 'hypothesis': 'python3-hypothesis', 'launch_pytest': 'launch_pytest',
    'ament_flake8': 'ament_flake8', 'xmlschema': 'python3-xmlschema', 'sros2': 'sros2', 'lxml': 'python3-lxml',
}
#: Modules without a rosdep key for Jazzy or Kilted: imported only inside the functions that need
#: them, and the CLI names the missing package in one line (cli.NOT_IN_ROSDEP).
NOT_IN_ROSDEP = ('scikit_posthocs', 'distributed')
#: Test-only modules without a rosdep key, imported only through pytest.importorskip: bids (pybids,
#: an outside reader of the study folder, test_study_bids).
TESTS_NOT_IN_ROSDEP = ('bids',)

TEST_HELPERS = {p.stem for p in (ROOT / 'test').glob('*.py')}


def _imports(path: Path):
    """(top-level module, at module level?) of every import in the file, importorskip's too."""
    tree = ast.parse(path.read_text(), str(path))
    top_level = {id(n) for n in tree.body}
    for node in ast.walk(tree):
        names = []
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and not node.level and node.module:
            names = [node.module]
        elif (isinstance(node, ast.Call) and getattr(node.func, 'attr', '') == 'importorskip'
              and node.args and isinstance(node.args[0], ast.Constant)):
            names = [node.args[0].value]
        for name in names:
            yield name.split('.')[0], id(node) in top_level


def _third_party(directory: str) -> dict[str, list[tuple[str, bool]]]:
    """module -> [(file, at module level)] for the modules outside the standard library and the
    package (and, under test/, its helper modules)."""
    found: dict[str, list] = {}
    for path in sorted((ROOT / directory).rglob('*.py')):
        for module, module_level in _imports(path):
            if module in sys.stdlib_module_names or module == 'fabric_guidance' or module in TEST_HELPERS:
                continue
            found.setdefault(module, []).append((path.relative_to(ROOT).as_posix(), module_level))
    return found


def _declared():
    root = ET.parse(ROOT / 'package.xml').getroot()
    exec_keys = {e.text.strip() for e in root.findall('exec_depend')} | {e.text.strip() for e in root.findall('depend')}
    return exec_keys, {e.text.strip() for e in root.findall('test_depend')}


def test_every_import_of_the_package_and_its_launch_files_is_an_exec_depend():
    exec_keys, _ = _declared()
    missing = []
    for directory in ('fabric_guidance', 'launch'):
        for module, where in _third_party(directory).items():
            if module in NOT_IN_ROSDEP:
                continue
            key = MODULE_KEYS.get(module)
            if key is None or key not in exec_keys:
                missing.append(f'{module} ({where[0][0]}): rosdep key {key or "unknown: add it to MODULE_KEYS"} '
                               'not an exec_depend of package.xml')
    assert not missing, '\n'.join(missing)


def test_every_import_of_the_tests_is_declared():
    exec_keys, test_keys = _declared()
    missing = [f'{module} ({where[0][0]}): rosdep key {MODULE_KEYS.get(module, "unknown")} not in package.xml'
               for module, where in _third_party('test').items()
               if module not in NOT_IN_ROSDEP + TESTS_NOT_IN_ROSDEP
               and MODULE_KEYS.get(module) not in exec_keys | test_keys]
    assert not missing, '\n'.join(missing)


def test_every_declared_key_is_imported():
    """No key rosdep would install for nothing (sensor_msgs was declared and never imported)."""
    exec_keys, test_keys = _declared()
    used = {MODULE_KEYS.get(m) for d in ('fabric_guidance', 'launch', 'test') for m in _third_party(d)}
    assert not (exec_keys | test_keys) - used, f'declared, imported nowhere: {sorted((exec_keys | test_keys) - used)}'


def test_a_module_without_a_rosdep_key_is_imported_only_where_it_is_used():
    """Without it everything else imports and starts; the command that needs it says in one line
    what to install."""
    from fabric_guidance.commands import cli
    package = _third_party('fabric_guidance')
    for module in NOT_IN_ROSDEP:
        assert module not in MODULE_KEYS
        at_module_level = [f for f, module_level in package.get(module, []) if module_level]
        assert not at_module_level, f'{module} imported at module level in {at_module_level}'
        assert module in cli.NOT_IN_ROSDEP


def test_a_missing_module_is_one_line_naming_it(monkeypatch, capsys):
    """`fabric-guidance analyze` in a workspace without scikit-posthocs."""
    import builtins
    from fabric_guidance.commands import cli
    real_import = builtins.__import__

    def no_posthocs(name, *args, **kwargs):
        if name.split('.')[0] == 'scikit_posthocs':
            raise ModuleNotFoundError(f"No module named '{name}'", name=name)
        return real_import(name, *args, **kwargs)
    monkeypatch.setattr(builtins, '__import__', no_posthocs)
    assert cli.main(['analyze', str(ROOT / 'test' / 'data' / 'table-identified-targets.csv')]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ['fabric-guidance analyze: error: the Python module scikit_posthocs is not installed: '
                   'pip install scikit-posthocs (it has no rosdep key)'], err
