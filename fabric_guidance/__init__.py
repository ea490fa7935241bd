"""fabric_guidance: directional guidance through a pneumatic fabric suit (Yokoe et al. 2025).

The package's top level holds `interface` (every topic and service) and four small utilities
(`paths`, `atomic`, `subcommand`, `workers`); everything else is in a package of its own
(docs/architecture.md). The modules that moved into packages keep their old import paths for
one release: importing `fabric_guidance.<old>` (or running `python -m fabric_guidance.<old>`)
warns with a DeprecationWarning and gives the module at its new path.
"""
import importlib
import importlib.abc
import importlib.machinery
import sys
import warnings

#: Old module path -> new module path (moved in 0.9; the old paths go in the release after).
MOVED = {
    'fabric_guidance.calibration_report': 'fabric_guidance.lab.calibration_report',
    'fabric_guidance.discovery_server': 'fabric_guidance.lab.discovery_server',
    'fabric_guidance.lab_network': 'fabric_guidance.lab.lab_network',
    'fabric_guidance.security_policy': 'fabric_guidance.lab.security_policy',
    'fabric_guidance.views': 'fabric_guidance.lab.views',
    'fabric_guidance.launch_support': 'fabric_guidance.graph.launch_support',
    'fabric_guidance.process_graph': 'fabric_guidance.graph.process_graph',
    'fabric_guidance.cli': 'fabric_guidance.commands.cli',
    'fabric_guidance.demo': 'fabric_guidance.commands.demo',
    'fabric_guidance.demo_command': 'fabric_guidance.commands.demo_command',
    'fabric_guidance.example_command': 'fabric_guidance.commands.example_command',
    'fabric_guidance.recover': 'fabric_guidance.commands.recover',
    'fabric_guidance.replay': 'fabric_guidance.commands.replay',
}


def moved_warning(old: str) -> str:
    return f'{old} moved to {MOVED[old]}; the old path goes in the next release'


class _MovedLoader(importlib.abc.Loader):
    """Gives the module at its new path under the old name. Under `python -m`, runpy asks for
    the code to run as __main__: a stub that runs the new module as __main__ (its relative
    imports then resolve in its own package)."""

    def create_module(self, spec):
        warnings.warn(moved_warning(spec.name), DeprecationWarning, stacklevel=2)
        module = importlib.import_module(MOVED[spec.name])
        self._own_spec = module.__spec__
        return module

    def exec_module(self, module):
        # The import machinery has set the old name's spec on the module: give it back its own.
        module.__spec__ = self._own_spec

    def get_code(self, fullname):
        source = (f'import runpy, warnings\n'
                  f'warnings.warn({moved_warning(fullname)!r}, DeprecationWarning)\n'
                  f'runpy.run_module({MOVED[fullname]!r}, run_name="__main__", alter_sys=True)\n')
        return compile(source, f'<{fullname}: moved to {MOVED[fullname]}>', 'exec')

    def is_package(self, fullname):
        return False


class _MovedFinder(importlib.abc.MetaPathFinder):
    def find_spec(self, fullname, path=None, target=None):
        if fullname in MOVED:
            return importlib.machinery.ModuleSpec(fullname, _MovedLoader())  # a loader per import
        return None


if not any(isinstance(f, _MovedFinder) for f in sys.meta_path):
    # First: only the old names answer, and no other finder (an editable install's) may find a stale file.
    sys.meta_path.insert(0, _MovedFinder())
