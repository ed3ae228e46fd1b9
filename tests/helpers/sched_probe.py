"""How late this machine wakes a process up: the allowance that latency tests add for a loaded machine.

A latency test on a shared machine measures two things at once: the endpoint's own delay (what the code
controls) and the operating system's delay in giving its processes a CPU (what other processes' load
controls). :class:`SchedulingProbe` measures the second in a process of its own, at the test's niceness, with
no GIL to share: it sleeps 1 ms at a time and records how late it wakes. A stop round trip crosses at most
``WAKEUPS_PER_ROUND_TRIP`` such wake-ups (client writes, endpoint loop reads, client reader thread reads,
requesting thread wakes), so a test allows ``budget + WAKEUPS_PER_ROUND_TRIP * probe.p99`` and reports both.
On an idle machine the probe's p99 is well under 1 ms, and the allowance is the budget itself.
"""

from __future__ import annotations

import json
import subprocess
import sys

WAKEUPS_PER_ROUND_TRIP = 4
"""Scheduler wake-ups on a request's round trip between two processes (see the module docstring)."""

_PROBE = """
import json, sys, time, select
late = []
while not select.select([sys.stdin], [], [], 0)[0]:
    before = time.monotonic()
    time.sleep(0.001)
    late.append(time.monotonic() - before - 0.001)
late.sort()
print(json.dumps({"samples": len(late), "p50_s": late[len(late) // 2], "p99_s": late[int(0.99 * (len(late) - 1))],
                  "max_s": late[-1]}), flush=True)
"""


class SchedulingProbe:
    """A process measuring its own wake-up lateness until :meth:`result` (use as a context manager)."""

    def __init__(self) -> None:
        self._process = subprocess.Popen([sys.executable, "-c", _PROBE], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        self.report: dict[str, float] = {}

    def result(self) -> dict[str, float]:
        """Stop probing; the wake-up lateness (``p50_s``, ``p99_s``, ``max_s``) and number of samples."""
        if not self.report:
            out, _ = self._process.communicate("stop\n", timeout=30.0)
            self.report = json.loads(out.strip().splitlines()[-1])
        return self.report

    def allowance(self, budget: float) -> float:
        """The latency budget plus the operating system's share on this machine now, s."""
        return budget + WAKEUPS_PER_ROUND_TRIP * self.result()["p99_s"]

    def __enter__(self) -> SchedulingProbe:
        return self

    def __exit__(self, *exc: object) -> None:
        if self._process.poll() is None:
            self._process.kill()
            self._process.wait(5.0)


__all__ = ["SchedulingProbe", "WAKEUPS_PER_ROUND_TRIP"]
