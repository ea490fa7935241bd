"""The times the fault tests measure against their deadlines, kept per module and printed at the
end (the worst of each kind), so that `pytest -s` shows the closing-note table's figures."""
from __future__ import annotations

import pytest


class DeadlineLog:
    def __init__(self, label: str):
        self.label = label
        self.times: dict[str, list[tuple[float, float]]] = {}

    def record(self, kind: str, seconds: float, deadline_s: float) -> None:
        self.times.setdefault(kind, []).append((seconds, deadline_s))
        print(f'\n[{self.label}] {kind}: {seconds:.3f} s (deadline {deadline_s:.3f} s)')

    def count(self, kind: str) -> int:
        return len(self.times.get(kind, ()))

    def report(self, title: str) -> None:
        if not self.times:
            return
        print(f'\n{title}:')
        for kind, times in self.times.items():
            worst, deadline = max(times)
            print(f'  {kind:<60} worst {worst:.3f} s of {len(times)}, deadline {deadline:.3f} s')

    def report_at_module_end(self, title: str):
        """A module-scoped autouse fixture that prints the worst times when the module ends:
        `report = LOG.report_at_module_end('worst times, ...')` at module level."""
        @pytest.fixture(scope='module', autouse=True, name=f'deadline_report_{id(self)}')
        def report():
            yield
            self.report(title)
        return report
