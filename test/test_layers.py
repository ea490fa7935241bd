"""The package's layers import one way only, and no two of its modules import each other.

From the bottom up (docs/architecture.md):

    0  paths, atomic, interface,          where files are; writing a file whole or not at all; topic
       subcommand, workers                names, types, QoS; the CLI pattern; the simulations' pool
    1  core                               the paper's algorithms, no ROS
    2  plc, lab                           the PLC link; what a lab sets up around the graph without
                                          ROS (DDS profile, discovery server, SROS2 policy, operator
                                          views, a calibration's report)
    3  sim, bag                           the simulator; bags (neither imports the other)
    4  experiments                        the paper's experiments and studies on sim
    5  study                              a live study with people: plan, session, study folder
    6  nodes                              the ROS nodes: thin wiring over the layers below
    7  graph                              starting the nodes as processes; launch files' helpers
    8  live_study                         the study session through the graph
    9  bench                              measurements; the chaos and soak runs
    10 commands                           what a person runs: the entry point (it imports a
                                          subcommand's module by name), demo, example, replay, recover

A module may import its own package and any lower layer; packages of the same layer do not
import each other. Every import counts, also those inside functions: a lazy import that runs
upward is still a layer running both ways.
"""
import ast
from pathlib import Path

import pytest

PACKAGE_DIR = Path(__file__).resolve().parents[1] / 'fabric_guidance'
LAYERS = {
    'paths': 0, 'atomic': 0, 'interface': 0, 'subcommand': 0, 'workers': 0,
    'core': 1,
    'plc': 2, 'lab': 2,
    'sim': 3, 'bag': 3,
    'experiments': 4,
    'study': 5,
    'nodes': 6,
    'graph': 7,
    'live_study': 8,
    'bench': 9,
    'commands': 10,
}
#: The top level: interface.py, the package's centre, and at most five small utilities.
TOP_LEVEL_MODULES = {'interface', 'paths', 'atomic', 'subcommand', 'workers'}


def _module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE_DIR.parent).with_suffix('').parts
    return '.'.join(parts[:-1] if parts[-1] == '__init__' else parts)


def _imports(path: Path, text: str | None = None):
    """(line, absolute module name) of every import of the package in the file."""
    module = _module_name(path)
    package = module if path.name == '__init__.py' else module.rpartition('.')[0]
    for node in ast.walk(ast.parse(path.read_text() if text is None else text, str(path))):
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.startswith('fabric_guidance'):
                    yield node.lineno, alias.name
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split('.')
                base = base[:len(base) - node.level + 1]
                target = '.'.join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ''
            if not target.startswith('fabric_guidance'):
                continue
            if node.module is None or (node.level and not node.module):
                # `from . import x`: x is a module of that package
                for alias in node.names:
                    yield node.lineno, f'{target}.{alias.name}'
            else:
                yield node.lineno, target


def _top(module: str) -> str:
    parts = module.split('.')
    return parts[1] if len(parts) > 1 else ''


SOURCES = sorted(PACKAGE_DIR.rglob('*.py'))


def test_every_module_has_a_layer():
    missing = sorted({_top(_module_name(p)) for p in SOURCES} - set(LAYERS) - {''})
    assert not missing, f'modules without a layer (add them to LAYERS and docs/architecture.md): {missing}'


def test_layers_import_one_way():
    wrong = []
    for path in SOURCES:
        me = _top(_module_name(path))
        if not me:
            continue
        for line, target in _imports(path):
            other = _top(target)
            if not other or other == me:
                continue
            if LAYERS[other] > LAYERS[me] or (LAYERS[other] == LAYERS[me]):
                wrong.append(f'{path.relative_to(PACKAGE_DIR.parent)}:{line} ({me}, layer {LAYERS[me]}) '
                             f'imports {target} ({other}, layer {LAYERS[other]})')
    assert not wrong, 'imports against the layers:\n' + '\n'.join(wrong)


def test_no_two_modules_import_each_other():
    graph = {}
    for path in SOURCES:
        graph.setdefault(_module_name(path), set()).update(t for _, t in _imports(path))
    known = set(graph)

    def resolve(name):
        # `from .x import y` names the module x (or the package): keep what exists.
        while name and name not in known:
            name = name.rpartition('.')[0]
        return name

    edges = {m: {resolve(t) for t in ts} - {m, ''} for m, ts in graph.items()}
    # A package's __init__ re-exporting its modules is not a cycle of the layers.
    cycles = sorted({tuple(sorted((a, b))) for a, ts in edges.items() for b in ts
                     if a in edges.get(b, ()) and not (a.startswith(b + '.') or b.startswith(a + '.'))})
    assert not cycles, 'modules importing each other: ' + ', '.join(f'{a} <-> {b}' for a, b in cycles)


@pytest.mark.parametrize('text, expected', [
    ('from ..core.power_law import PowerLaw', 'fabric_guidance.core.power_law'),
    ('from . import modbus', 'fabric_guidance.sim.modbus'),
    ('import fabric_guidance.nodes.common', 'fabric_guidance.nodes.common'),
])
def test_the_import_reader_resolves_relative_imports(text, expected):
    """The guard itself: an import in sim/ resolves to the module it names."""
    assert [t for _, t in _imports(PACKAGE_DIR / 'sim' / 'probe.py', text)] == [expected]


def test_no_module_file_name_is_used_twice():
    """One name, one room: a module's file name says where it lives (package files excepted)."""
    seen: dict[str, list[str]] = {}
    for path in SOURCES:
        if not (path.name.startswith('__') and path.name.endswith('__.py')):
            seen.setdefault(path.name, []).append(str(path.relative_to(PACKAGE_DIR)))
    repeated = {name: paths for name, paths in seen.items() if len(paths) > 1}
    assert not repeated, f'file names used more than once: {repeated}'


def test_the_top_level_keeps_interface_and_five_utilities():
    """Everything else lives in a package named after what it is (docs/architecture.md)."""
    loose = {p.stem for p in PACKAGE_DIR.glob('*.py') if p.name != '__init__.py'}
    assert loose == TOP_LEVEL_MODULES, f'loose modules at the top: {sorted(loose - TOP_LEVEL_MODULES)}'
    assert len(TOP_LEVEL_MODULES - {'interface'}) <= 5
