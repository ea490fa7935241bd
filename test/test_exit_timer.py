"""nodes/exit_timer.py: the process ends with the armed status while the GIL is held for good,
which no Python timer could do."""
import subprocess
import sys
import textwrap

import pytest

from fabric_guidance.nodes import exit_timer

#: Far above the armed delays below and a loaded machine's interpreter start-up.
DEADLINE_S = 60.0

HELD = textwrap.dedent('''
    import ctypes, sys
    from fabric_guidance.nodes import exit_timer
    assert exit_timer.arm(float(sys.argv[1]), int(sys.argv[2]))
    print('armed', flush=True)
    ctypes.PyDLL(None).sleep(600)   # keeps the GIL (PyDLL does not release it) and never returns
''')


@pytest.mark.skipif(not sys.platform.startswith('linux'), reason='POSIX timers of glibc')
@pytest.mark.parametrize('code', [0, 3])
def test_the_armed_status_ends_a_process_whose_gil_is_held(code):
    proc = subprocess.run([sys.executable, '-c', HELD, '0.2', str(code)], capture_output=True, text=True,
                          timeout=DEADLINE_S)
    assert proc.stdout == 'armed\n', proc.stderr
    assert proc.returncode == code, proc.stderr


def test_the_event_structure_is_linux_s():
    # struct sigevent is 64 bytes on Linux (glibc's __SIGEV_MAX_SIZE); arm() refuses any other size.
    assert exit_timer.sizeof_sigevent() == 64
