"""A process exit that needs no Python: after a delay, libc's `_exit(code)` runs on a thread of the
C library's own, so it still ends the process while another thread holds the GIL and never lets
go of it.

Why: after its vent a node tears down its DDS entities, and Fast DDS can deadlock there (an entity's
deletion waiting on the participant's event thread, which waits on a lock the deletion holds; open
upstream as eProsima/Fast-DDS#6502). rclpy makes that call with the GIL held, so no Python timer can
run: only faulthandler's watchdog (a C thread) could end the process, and it can only exit with
status 1. The vent, which is what matters to the suit, was already done; the status should say so.

POSIX timers with SIGEV_THREAD notification call `function(sigev_value)` on a new thread. With
`_exit` as the function and the status as the value's integer, the kernel timer ends the process
without entering the interpreter. Linux with glibc only (what a lab's Ubuntu has); elsewhere
`arm()` says it could not and the caller keeps faulthandler's exit.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import sys

CLOCK_MONOTONIC = 1
SIGEV_THREAD = 2


class _Sigval(ctypes.Union):
    _fields_ = [('sival_int', ctypes.c_int), ('sival_ptr', ctypes.c_void_p)]


class _ThreadNotify(ctypes.Structure):
    _fields_ = [('function', ctypes.c_void_p), ('attribute', ctypes.c_void_p)]


class _Sigevent(ctypes.Structure):
    """struct sigevent of Linux: 64 bytes, the thread notification in its padded union."""
    class _Un(ctypes.Union):
        _fields_ = [('pad', ctypes.c_int * 12), ('thread', _ThreadNotify)]
    _fields_ = [('value', _Sigval), ('signo', ctypes.c_int), ('notify', ctypes.c_int), ('un', _Un)]


class _Timespec(ctypes.Structure):
    _fields_ = [('tv_sec', ctypes.c_long), ('tv_nsec', ctypes.c_long)]


class _Itimerspec(ctypes.Structure):
    _fields_ = [('interval', _Timespec), ('value', _Timespec)]


def _libc():
    libc = ctypes.CDLL(None, use_errno=True)
    if hasattr(libc, 'timer_create'):
        return libc, libc               # glibc 2.34 and later: timers are in libc
    rt = ctypes.util.find_library('rt')
    return libc, ctypes.CDLL(rt, use_errno=True)


def arm(delay_s: float, code: int) -> bool:
    """End the process with status `code` `delay_s` seconds from now, whatever holds the GIL then.
    False (nothing armed) where the C library has no POSIX timers with thread notification."""
    if not sys.platform.startswith('linux') or sizeof_sigevent() != 64:
        return False
    try:
        libc, rt = _libc()
        event = _Sigevent()
        event.notify = SIGEV_THREAD
        event.value.sival_int = int(code)
        event.un.thread.function = ctypes.cast(libc._exit, ctypes.c_void_p).value
        timer = ctypes.c_void_p()
        if rt.timer_create(CLOCK_MONOTONIC, ctypes.byref(event), ctypes.byref(timer)) != 0:
            return False
        seconds = max(delay_s, 0.001)
        when = _Itimerspec(value=_Timespec(int(seconds), int((seconds % 1.0) * 1e9)))
        return rt.timer_settime(timer, 0, ctypes.byref(when), None) == 0
    except (OSError, AttributeError):
        return False


def sizeof_sigevent() -> int:
    return ctypes.sizeof(_Sigevent)
