"""The headset library's C# core (hololens/): it builds with Debian's mcs and its own tests pass
under mono. Its build output stays out of git."""
import re
import subprocess

from fabric_guidance.bench.build_lock import locked_run
from headset_harness import EXE, HOLOLENS, build_harness
from rosgraph import ROOT


def test_the_csharp_core_builds_and_its_tests_pass():
    build_harness()
    done = locked_run(['make', '--no-print-directory', '-C', str(HOLOLENS), 'test'], EXE.parent, timeout=300)
    summary = re.search(r'^(\d+) passed, (\d+) failed$', done.stdout, re.M)
    assert done.returncode == 0 and summary, done.stdout + done.stderr
    assert int(summary.group(1)) >= 10 and summary.group(2) == '0', summary.group(0)


def test_the_build_output_is_not_tracked_and_unity_does_not_import_it():
    ignored = subprocess.run(['git', 'check-ignore', '-q', 'hololens/build~/HeadsetHarness.exe'], cwd=ROOT)
    assert ignored.returncode == 0
    # Unity imports every folder of the package except those ending in '~' (or starting with '.'):
    # a DLL of the core there would define its types twice (CS0433); the tests and the harness
    # (no assembly definition, a Main each) would be warned about.
    assert 'BUILD := build~' in (HOLOLENS / 'Makefile').read_text()
    parts = [p.relative_to(HOLOLENS).parts for p in HOLOLENS.rglob('*.cs')]
    outside = [p for p in parts if p[0] != 'Runtime' and not any(part.endswith('~') for part in p)]
    assert not outside, outside
    assert EXE.parent.name.endswith('~') and EXE.is_relative_to(HOLOLENS)
