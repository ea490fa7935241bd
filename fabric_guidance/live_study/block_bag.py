"""One bag per block: the package's bag_recorder, started before a block's first trial into the
folder the study store reserved for it (store.SessionStore.bag_path) and closed after its last.

The recorder is a process of its own, not a writer in the session's process: the session's
operator thread then never spends its time serializing messages (the key press is judged on
the gaze it keeps), the recorder keeps its own deep queues, and a session killed without
warning (SIGKILL, a crash) leaves a complete bag: the recorder asks the kernel for SIGINT when
its parent dies (PR_SET_PDEATHSIG) and closes the bag with its metadata as on Ctrl-C. The
kernel means the thread that started it: call start() from the session's main thread, not
from a thread that ends before the block does. A
recorder killed itself loses at most its last flush period (`fabric-guidance recover BAG`).

    rec = BlockRecorder(op, namespace='/')
    rec.start(store.bag_path(block))     # returns once the recorder hears gaze and confirm
    ...                                  # the block's trials
    rec.stop()                           # the bag closed, readable by any rosbag2 reader
"""
from __future__ import annotations

import os
from pathlib import Path
import signal
import subprocess
import sys
import time

from .. import interface

#: The recorder's node name (one recorder per session graph).
RECORDER_NODE = 'study_bag_recorder'
#: What is received goes to disk this often: at most this is lost if the recorder is killed [s].
FLUSH_PERIOD_S = 0.5
#: The recorder's start (interpreter, rclpy, discovery) may take seconds on a loaded machine [s].
START_TIMEOUT_S = 30.0
#: SIGINT to a closed bag; then SIGKILL (the flushed chunks stay recoverable) [s].
STOP_TIMEOUT_S = 15.0
#: The recorder must hear these before the block's first trial.
REQUIRED = (interface.GAZE, interface.CONFIRM)

PR_SET_PDEATHSIG = 1


class BlockRecorderError(RuntimeError):
    """The block's recorder did not start or stop (the message says why and where its log is)."""


def _topic(name: str, namespace: str) -> str:
    ns = namespace.rstrip('/')
    return name if name.startswith('/') else f'{ns}/{name}'


class BlockRecorder:
    """bag_recorder as a child process on the operator's domain (see the module docstring).

    op: an Operator (its node sees the recorder's subscriptions: start() waits on them) or a
    domain id (start() then returns once the process runs, without waiting on discovery)."""

    def __init__(self, op_or_domain, namespace: str = '/'):
        self.op = None if isinstance(op_or_domain, int) or op_or_domain is None else op_or_domain
        if self.op is not None:
            self.domain_id = self.op.context.get_domain_id()
        else:
            self.domain_id = op_or_domain
        self.namespace = '/' + namespace.strip('/')
        self.process: subprocess.Popen | None = None
        self.path: Path | None = None
        self.log_path: Path | None = None

    def start(self, path: str | Path) -> Path:
        """Record into `path` (a folder that must not exist); returns when the recorder listens."""
        if self.process is not None:
            raise BlockRecorderError(f'a block is already recorded into {self.path}')
        self.path = Path(path)
        if self.path.exists():
            raise BlockRecorderError(f'{self.path}: exists; a block bag goes into a new folder')
        self.log_path = self.path.with_name(self.path.name + '_recorder.log')
        env = dict(os.environ)
        if self.domain_id is not None:
            env['ROS_DOMAIN_ID'] = str(self.domain_id)
        cmd = [sys.executable, '-m', __name__, str(os.getpid()), '--ros-args', '-r', f'__node:={RECORDER_NODE}',
               '-r', f'__ns:={self.namespace}', '-p', f'output:={self.path}',
               '-p', f'flush_period_s:={FLUSH_PERIOD_S}']
        with open(self.log_path, 'ab') as log:
            self.process = subprocess.Popen(cmd, env=env, stdout=log, stderr=subprocess.STDOUT,
                                            stdin=subprocess.DEVNULL)
        self._wait_listening()
        return self.path

    def _wait_listening(self) -> None:
        deadline = time.monotonic() + START_TIMEOUT_S
        while True:
            if self.process.poll() is not None:
                self.process = None
                raise BlockRecorderError(f'the block recorder ended at its start (exit code '
                                         f'{self.process_returncode()}); see {self.log_path}')
            if self.listening():
                return
            if time.monotonic() > deadline:
                self.stop()
                raise BlockRecorderError(f'the block recorder did not subscribe within {START_TIMEOUT_S:.0f} s; '
                                         f'see {self.log_path}')
            time.sleep(0.05)

    def process_returncode(self):
        return None if self.process is None else self.process.returncode

    def listening(self) -> bool:
        """The recorder's subscriptions to REQUIRED are on the graph (always True without an
        Operator, once the bag folder exists)."""
        if self.op is None:
            return self.path is not None and self.path.exists()
        node = self.op.node
        for name in REQUIRED:
            infos = node.get_subscriptions_info_by_topic(_topic(name, self.namespace))
            if not any(i.node_name == RECORDER_NODE for i in infos):
                return False
        return True

    def stop(self) -> Path | None:
        """Close the bag (SIGINT, as Ctrl-C); the bag's folder, None when nothing was recorded."""
        proc, self.process = self.process, None
        if proc is None:
            return None
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
            try:
                proc.wait(STOP_TIMEOUT_S)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
                raise BlockRecorderError(f'{self.path}: the recorder did not close the bag within '
                                         f'{STOP_TIMEOUT_S:.0f} s and was killed; `fabric-guidance recover '
                                         f'{self.path}` makes the flushed part a complete bag') from None
        return self.path


class BlockBags:
    """The study store (study.store.SessionStore) as the session driver sees it, with a bag per
    block: begin(block) at the block's start (its condition set, before its first trial) closes
    the previous bag and records into the store's reserved folder; the bag is closed when the
    store records the block done, or by close() (a stopped or failed session: that bag stays
    readable and the redone block gets the next run)."""

    def __init__(self, op, store, namespace: str = '/', say=lambda line: None):
        self.store, self.say = store, say
        self.recorder = BlockRecorder(op, namespace)
        self.block = None

    def begin(self, block) -> None:
        """Record `block` into its reserved folder. A recorder that cannot start (its log says
        why) costs the block's bag, not the participant's block: one line, and the trials are
        written as always."""
        self.close()
        path = self.store.bag_path(block)
        try:
            self.recorder.start(path)
        except (BlockRecorderError, OSError) as exc:
            self.say(f'  block {block.order}: no bag ({exc}); its trials are recorded as always')
            return
        self.block = block
        self.say(f'  recording block {block.order} into {path.name}')

    def record(self, step) -> None:
        self.store.record(step)
        if self.block is not None and any(b.key == self.block.key for b in step.blocks):
            self.close()

    def close(self) -> None:
        self.block = None
        try:
            self.recorder.stop()
        except BlockRecorderError as exc:     # killed: the flushed part is recoverable
            self.say(f'  {exc}')

    def __getattr__(self, name):
        return getattr(self.store, name)


def _die_with_parent(parent: int) -> None:
    """SIGINT when the session process ends (Linux); the bag is then closed as on Ctrl-C."""
    try:
        import ctypes
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(PR_SET_PDEATHSIG, signal.SIGINT)
    except (OSError, AttributeError):
        return
    if os.getppid() != parent:          # the parent died before the request: nothing to record
        raise SystemExit(0)


def main() -> int:
    parent = int(sys.argv.pop(1))
    _die_with_parent(parent)
    from ..nodes.bag_recorder import main as recorder_main
    return recorder_main()


if __name__ == '__main__':
    sys.exit(main())
