"""A fault-injecting TCP proxy for the fault tests and the chaos run: put it between a client
(plc_output) and a server (mock_plc) and break the link on purpose, switching faults at run time.

Faults (each counted, so a test can check that it really happened):

- ``drop()``: the link stays up but every byte either way is lost (a dead switch port that
  keeps the link light on); new connections are accepted and lose everything too.
- ``disconnect()``: every open connection is closed on both sides, and new ones are closed as
  soon as they are accepted (the PLC's cable pulled, the host answering with resets).
- ``half_open()``: the server side of every open connection is closed, while the client side
  stays open and silent: the client only finds out by its own timeout (the PLC rebooted
  without telling). New connections work.
- ``hold(seconds, when=...)``: on the connections open now, from the first client->server
  chunk for which ``when(chunk)`` is true, that direction is delayed by ``seconds``, in order.
  Held bytes are still delivered after the client has closed its socket, as a slow network
  delivers what was already sent: the way an old request can reach the server after a newer
  one sent on a new connection. New connections are not delayed.
- ``delay(seconds)``: every chunk read from now on, on any connection, either way, is
  delivered ``seconds`` late, in order.
- ``heal()``: back to forwarding everything at once (held chunks already queued still arrive
  late).

Threads: one accept thread, and per connection a reader and a writer per direction (the
writer waits until each chunk is due). The Modbus client sends one request per send() and
waits for the answer, so a chunk is a request in practice.
"""
from __future__ import annotations

import queue
import socket
import threading
import time
from typing import Callable

_EOF = b''


class _Link:
    """One proxied connection: client socket, server socket, two directions."""

    def __init__(self, proxy: 'FaultProxy', client: socket.socket, server: socket.socket):
        self.proxy, self.client, self.server = proxy, client, server
        self.muted = False           # half-open: the client side hears nothing, ever
        self.client_closed = False   # the client closed its side (EOF read)
        self.hold_when: Callable[[bytes], bool] | None = None
        self.hold_s = 0.0
        self.holding = False
        self.closed = threading.Event()
        self._threads = []
        for src, dst, upstream in ((client, server, True), (server, client, False)):
            q: queue.Queue = queue.Queue()
            self._threads.append(threading.Thread(target=self._read, args=(src, q, upstream), daemon=True))
            self._threads.append(threading.Thread(target=self._write, args=(dst, q, upstream), daemon=True))
        for t in self._threads:
            t.start()

    def _read(self, src: socket.socket, q: queue.Queue, upstream: bool) -> None:
        p = self.proxy
        while True:
            try:
                data = src.recv(65536)
            except OSError:
                data = _EOF
            if not data:
                if upstream:
                    self.client_closed = True
                if not (self.muted and not upstream):   # a half-open client never hears the close
                    q.put((time.monotonic(), _EOF, False))
                return
            now = time.monotonic()
            if self.muted or p.mode == 'drop':
                p.count('dropped_chunks')
                continue
            held = False
            if upstream and self.hold_when is not None and (self.holding or self.hold_when(data)):
                self.holding = held = True
                p.count('held_chunks')
            due = now + (self.hold_s if held else 0.0) + p.delay_s
            q.put((due, data, held))

    def _write(self, dst: socket.socket, q: queue.Queue, upstream: bool) -> None:
        p = self.proxy
        while True:
            try:
                due, data, held = q.get(timeout=0.1)
            except queue.Empty:
                if self.closed.is_set():
                    return
                continue
            wait = due - time.monotonic()
            if wait > 0:
                time.sleep(wait)
            try:
                if data is _EOF:
                    dst.shutdown(socket.SHUT_WR)
                    return
                dst.sendall(data)
            except OSError:
                return
            if held:
                p.count('held_delivered')
                if self.client_closed:
                    p.count('delivered_after_client_closed')

    def close_server_side(self) -> None:
        try:
            self.server.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass
        self.server.close()

    def close(self) -> None:
        self.closed.set()
        for s in (self.client, self.server):
            try:
                s.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
            s.close()


class FaultProxy:
    """Listens on 127.0.0.1:<port> (an OS-chosen port) and forwards to upstream."""

    def __init__(self, upstream_host: str, upstream_port: int, listen_host: str = '127.0.0.1'):
        self.upstream = (upstream_host, upstream_port)
        self.mode = 'pass'        # 'pass', 'drop' or 'refuse'
        self.delay_s = 0.0
        self.counts: dict[str, int] = {}
        self._lock = threading.Lock()
        self.links: list[_Link] = []
        self._listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self._listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self._listener.bind((listen_host, 0))
        self._listener.listen(16)
        self._listener.settimeout(0.1)
        self.host, self.port = self._listener.getsockname()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._accept_loop, name='faultproxy', daemon=True)
        self._thread.start()

    def count(self, what: str, n: int = 1) -> None:
        with self._lock:
            self.counts[what] = self.counts.get(what, 0) + n

    def get(self, what: str) -> int:
        with self._lock:
            return self.counts.get(what, 0)

    def _accept_loop(self) -> None:
        while not self._stop.is_set():
            try:
                client, _ = self._listener.accept()
            except socket.timeout:
                continue
            except OSError:
                return
            if self.mode == 'refuse':
                self.count('refused')
                client.close()
                continue
            try:
                server = socket.create_connection(self.upstream, timeout=2.0)
            except OSError:
                self.count('upstream_unreachable')
                client.close()
                continue
            server.settimeout(None)
            client.settimeout(None)
            self.count('accepted')
            with self._lock:
                self.links = [link for link in self.links if not link.closed.is_set()]
                self.links.append(_Link(self, client, server))

    def _open_links(self) -> list[_Link]:
        with self._lock:
            return [link for link in self.links if not link.closed.is_set()]

    # ---- faults
    def drop(self) -> None:
        self.mode = 'drop'

    def disconnect(self) -> None:
        self.mode = 'refuse'
        for link in self._open_links():
            link.close()
            self.count('disconnected')

    def half_open(self) -> None:
        for link in self._open_links():
            link.muted = True
            link.close_server_side()
            self.count('half_opened')

    def hold(self, seconds: float, when: Callable[[bytes], bool] = lambda data: True) -> None:
        for link in self._open_links():
            link.hold_s, link.hold_when = seconds, when

    def delay(self, seconds: float) -> None:
        self.delay_s = seconds

    def heal(self) -> None:
        self.mode, self.delay_s = 'pass', 0.0

    def close(self) -> None:
        self._stop.set()
        self._listener.close()
        self._thread.join(2)
        for link in self._open_links():
            link.close()

    def __enter__(self) -> 'FaultProxy':
        return self

    def __exit__(self, *_exc) -> None:
        self.close()


def is_modbus_write_multiple(data: bytes) -> bool:
    """A Modbus TCP frame with function code 16 (write multiple registers): the command write.
    (MBAP header: transaction id, protocol id, length, unit id; then the function code.)"""
    return len(data) > 7 and data[7] == 0x10
