"""Run one command under an address-space limit and a time limit, and measure its peak memory.

:func:`run_limited` starts this file as a script in a bare interpreter (``python -I -S launcher.py RUSAGE_FILE
LIMIT_BYTES COMMAND...``), so the file imports only the standard library. As a script it forks, sets RLIMIT_AS in the child (inherited by the command's own children) and execs the command, then
writes ``"<wait status> <ru_maxrss KiB> <user + system CPU s>"`` to RUSAGE_FILE and exits with the command's code (128 + signal if
killed). A bare launcher is needed because Linux carries a process's peak RSS across fork and exec: started
straight from a large parent (a batch driver, a Ray worker), the command would report at least the parent's RSS.
"""

from __future__ import annotations

import os
import resource
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class LimitedRun:
    """How a command run by :func:`run_limited` ended."""

    returncode: int
    """Exit code of the command, 128 + N if it died of signal N (137: SIGKILL, e.g. the kernel's OOM killer);
    -9 if the time limit killed the process group."""
    seconds: float
    """Wall time, seconds."""
    peak_mb: float | None
    """Peak resident memory of the command and the children it waited for, MiB; None if killed at the time limit."""
    timed_out: bool
    """True if the process group was killed at the time limit."""
    cpu_s: float | None = None
    """CPU time (user + system) of the command and the children it waited for, seconds; None if killed at the
    time limit. Unlike wall time it does not depend on how busy the machine is."""


def run_limited(command: list[str], log_path: str | Path, timeout_s: float, memory_limit_mb: int = 0,
                env: dict[str, str] | None = None, active: set[int] | None = None) -> LimitedRun:
    """Run ``command`` in its own session with stdout and stderr to ``log_path``.

    Args:
        command: program and arguments.
        log_path: file receiving the output.
        timeout_s: wall-time limit, seconds; the whole process group is killed after it.
        memory_limit_mb: RLIMIT_AS of the command, MiB (0: none); exceeding it fails its allocations.
        env: environment (default: this process's).
        active: if given, holds the command's process-group id while it runs, so that a caller running
            several commands from threads can kill them all when interrupted (a new session does not get
            the terminal's Ctrl-C, and only the main thread sees KeyboardInterrupt).
    """
    log_path = Path(log_path)
    log_path.parent.mkdir(parents=True, exist_ok=True)
    rusage_path = log_path.with_name(f".{log_path.name}.rusage")
    rusage_path.unlink(missing_ok=True)
    launcher = [sys.executable, "-I", "-S", __file__, str(rusage_path), str(memory_limit_mb * 2**20)]
    start = time.perf_counter()
    timed_out = False
    with open(log_path, "wb") as log:
        process = subprocess.Popen([*launcher, *command], stdout=log, stderr=subprocess.STDOUT,
                                   stdin=subprocess.DEVNULL, env=env, start_new_session=True)
        if active is not None:
            active.add(process.pid)
        try:
            process.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            timed_out = True
        finally:
            if process.poll() is None:  # timed out, or this thread was interrupted
                try:
                    os.killpg(process.pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass
                process.wait()
            if active is not None:
                active.discard(process.pid)
    seconds = time.perf_counter() - start
    try:
        status, maxrss_kib, cpu_s = rusage_path.read_text().split()
        rusage_path.unlink()
        return LimitedRun(os.waitstatus_to_exitcode(int(status)), seconds, int(maxrss_kib) / 1024.0, timed_out, float(cpu_s))
    except (OSError, ValueError):  # the launcher was killed before it could report
        return LimitedRun(process.returncode, seconds, None, timed_out)


def main() -> int:
    rusage_file, limit, command = sys.argv[1], int(sys.argv[2]), sys.argv[3:]
    pid = os.fork()
    if pid == 0:
        try:
            if limit > 0:
                resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
            os.execvp(command[0], command)
        except OSError as exc:
            sys.stderr.write(f"cannot run {command[0]}: {exc}\n")
        os._exit(127)
    _, status, usage = os.wait4(pid, 0)
    with open(rusage_file, "w") as f:
        f.write(f"{status} {usage.ru_maxrss} {usage.ru_utime + usage.ru_stime}")
    code = os.waitstatus_to_exitcode(status)
    return code if code >= 0 else 128 - code


if __name__ == "__main__":
    sys.exit(main())
