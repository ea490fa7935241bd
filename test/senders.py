"""The sender thread the graph tests' upstream stand-ins share (test_graph.HoloLensStub,
test_faults_process.Stub, test_node_pressure_controller.FakeUpstream): tick() every period_s
on a daemon thread until close(); `sending` is the switch a test clears to stop the gaze."""
import threading
import time


class PeriodicSender:
    period_s = 0.02

    def start(self, sending: bool = True) -> None:
        """Call at the end of the subclass's __init__, once tick() has what it needs; sending
        False: silent from the first tick until `sending` is set."""
        self.sending = threading.Event()
        if sending:
            self.sending.set()
        self._stop = False
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def tick(self) -> None:
        raise NotImplementedError

    def _run(self):
        while not self._stop:
            self.tick()
            time.sleep(self.period_s)

    def close(self):
        self._stop = True
        self._thread.join(2)
