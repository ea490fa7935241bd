"""The chaos run's HoloLens stand-in: gaze datagrams to gaze_bridge, paused or flooded on demand."""
from __future__ import annotations

import socket
import threading
import time

from ..core.gaze_wire import encode_datagram

#: Gaze datagrams per second while the stream is flooded (the HoloLens sends 30 to 60).
FLOOD_RATE_HZ = 2000.0


class GazeStub:
    """The HoloLens stand-in: valid gaze datagrams (looking ahead) at 60 Hz to gaze_bridge;
    `mode` 'send', 'pause' (nothing) or 'flood' (FLOOD_RATE_HZ)."""

    def __init__(self, port: int):
        self.port, self.seq, self.mode, self.sent = port, 0, 'send', 0
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name='gaze-stub', daemon=True)
        self._thread.start()

    def _run(self) -> None:
        next_s = time.monotonic()
        while not self._stop.is_set():
            mode = self.mode
            if mode != 'pause':
                datagram = encode_datagram(self.seq, time.monotonic(), (0.0, 1.2, 0.0), (0.0, 0.0, 1.0),
                                           (0.0, 1.2, 0.0), (0.0, 0.0, 0.0, 1.0), True)
                try:
                    self.sock.sendto(datagram, ('127.0.0.1', self.port))
                    self.sent += 1
                except OSError:   # the bridge restarting: the datagram is lost, as on Wi-Fi
                    pass
                self.seq += 1
            next_s += 1 / FLOOD_RATE_HZ if mode == 'flood' else 1 / 60
            self._stop.wait(max(0.0, next_s - time.monotonic()))
            if next_s < time.monotonic() - 0.1:   # fell behind (loaded machine): resume from now
                next_s = time.monotonic()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2)
        self.sock.close()
