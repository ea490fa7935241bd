"""The package as ROS 2 and colcon see it, and the core's independence from ROS."""
import ast
import fnmatch
import re
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
ROS_MODULES = ('rclpy', 'std_msgs', 'std_srvs', 'geometry_msgs', 'sensor_msgs', 'diagnostic_msgs',
               'visualization_msgs', 'rosidl', 'rcl_interfaces', 'builtin_interfaces')


def test_importing_the_core_loads_no_ros_module():
    code = ('import sys, fabric_guidance.core, fabric_guidance.sim.worked_example; '
            f'print([m for m in sys.modules if m.split(".")[0].startswith({ROS_MODULES!r})])')
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, check=True, cwd=ROOT)
    assert out.stdout.strip() == '[]'


def test_core_source_has_no_ros_import():
    for path in (ROOT / 'fabric_guidance' / 'core').glob('*.py'):
        for node in ast.walk(ast.parse(path.read_text())):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                     else [node.module or ''] if isinstance(node, ast.ImportFrom) else [])
            assert not any(n.split('.')[0].startswith(ROS_MODULES) for n in names), f'{path.name} imports {names}'


def test_package_xml_is_format_3_ament_python_with_the_dependencies():
    root = ET.parse(ROOT / 'package.xml').getroot()
    assert root.get('format') == '3'
    assert root.findtext('name') == 'fabric_guidance'
    assert root.find('export/build_type').text == 'ament_python'
    exec_deps = {e.text for e in root.findall('exec_depend')}
    assert {'rclpy', 'std_msgs', 'std_srvs', 'geometry_msgs', 'diagnostic_msgs', 'python3-numpy',
            'python3-scipy', 'python3-pymodbus', 'python3-transforms3d', 'python3-yaml'} <= exec_deps
    assert {'launch_pytest', 'python3-pytest'} <= {e.text for e in root.findall('test_depend')}
    # that they are all the imports: test_dependencies.py


def test_colcon_reads_no_wheel_pins():
    """colcon reads package.xml, setup.py and setup.cfg: the ROS wheels must not be in them."""
    for name in ('package.xml', 'setup.py', 'setup.cfg'):
        assert 'ros-rclpy' not in (ROOT / name).read_text(), name
    assert 'ros-rclpy[fastrtps]==' in (ROOT / 'requirements' / 'standalone.txt').read_text()


def test_ament_layout():
    assert (ROOT / 'resource' / 'fabric_guidance').is_file()
    cfg = (ROOT / 'setup.cfg').read_text()
    assert 'script_dir=$base/lib/fabric_guidance' in cfg and 'install_scripts=$base/lib/fabric_guidance' in cfg
    setup = (ROOT / 'setup.py').read_text()
    for needle in ("'share/ament_index/resource_index/packages'", "glob('launch/*.launch.py')"):
        assert needle in setup
    # Every file under config/ is installed (ROS parameter files, hardware description, ...).
    patterns = re.findall(r"glob\('(config/[^']+)'\)", setup)
    files = [p.relative_to(ROOT).as_posix() for p in (ROOT / 'config').rglob('*') if p.is_file()]
    missed = [f for f in files if not any(fnmatch.fnmatch(f, pat) and
                                          f.count('/') == pat.count('/') for pat in patterns)]
    assert files and not missed, f'setup.py data_files install none of {missed}'


def test_example_prints_the_worked_example(tmp_path):
    out = subprocess.run([sys.executable, '-m', 'fabric_guidance.commands.cli', 'example', '--out', str(tmp_path)],
                         capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert out.returncode == 0, out.stderr
    assert '4 of 4 targets found' in out.stdout
    assert (tmp_path / 'demo-wearer.yaml').is_file()


def test_analyze_is_a_subcommand_of_the_cli(capsys):
    from fabric_guidance.commands.cli import main
    table = ROOT / 'test' / 'data' / 'table-identified-targets.csv'
    assert main(['analyze', str(table)]) == 0
    assert 'Friedman chi-square = 16.837' in capsys.readouterr().out


def _sim_imports():
    """{module: set of sim modules it imports}, function-level imports included."""
    sim = ROOT / 'fabric_guidance' / 'sim'
    names = {p.stem for p in sim.glob('*.py')}
    graph = {}
    for path in sim.glob('*.py'):
        found = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.level == 1:
                mods = [node.module] if node.module else [a.name for a in node.names]
                found |= {m.split('.')[0] for m in mods if m.split('.')[0] in names}
        graph[path.stem] = found - {path.stem}
    return graph


def test_no_module_of_sim_imports_another_in_a_cycle():
    graph = _sim_imports()
    done, stack = set(), []

    def visit(name):
        if name in stack:
            cycle = stack[stack.index(name):] + [name]
            raise AssertionError('import cycle in sim/: ' + ' -> '.join(cycle))
        if name in done:
            return
        stack.append(name)
        for dep in sorted(graph[name]):
            visit(dep)
        stack.pop()
        done.add(name)

    for name in sorted(graph):
        visit(name)


def test_sim_imports_nothing_above_it():
    """sim/ sits on core and paths: it imports no experiments, nodes, bag, demo or cli."""
    above = ('experiments', 'nodes', 'bag', 'bench', 'demo', 'cli', 'replay', 'subcommand')
    for path in (ROOT / 'fabric_guidance' / 'sim').glob('*.py'):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.level == 2 and node.module:
                assert node.module.split('.')[0] not in above, \
                    f'sim/{path.name} imports ..{node.module}'
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                mods = ([a.name for a in node.names] if isinstance(node, ast.Import)
                        else [node.module or ''])
                for m in mods:
                    parts = m.split('.')
                    assert not (parts[0] == 'fabric_guidance' and len(parts) > 1
                                and parts[1] in above), f'sim/{path.name} imports {m}'
