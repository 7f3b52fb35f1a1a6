"""Processes a run starts never outlive it, and a stop signal ends a run the way Ctrl-C does.

- `die_with_parent(parent_pid)`, first thing in a worker process (a render worker, a training
  rank): on Linux, prctl(PR_SET_PDEATHSIG, SIGKILL) has the kernel kill the worker as soon as its
  parent exits, however the parent ends (kill -9 included); elsewhere a daemon thread checks the
  parent's pid every PARENT_POLL_S seconds and ends the worker. A parent that died before the call
  is caught too. Without this, workers of a killed run were re-parented to init, finished the
  scenes queued to them (racing the rerun) and kept the run's stdout open.
- `exec_dies_with_parent`, a subprocess `preexec_fn`: the same for an executable a worker runs
  (Blender), on Linux (the setting survives exec).
- `stop_signals()`, around a command in its main process: SIGTERM and SIGHUP raise `Stopped` (a
  KeyboardInterrupt) like SIGINT does, so the run's own teardown (stop the workers, keep what is
  complete) runs for each.
- `stop_processes(processes)`: terminate, wait briefly, then kill what is left.
- `kill_tree_when_gone(pid)`: for process trees a library starts and does not tie to the run (a
  local Ray cluster's raylet, agents and workers): a watcher process notes every process below
  `pid` as it appears and kills them once `pid` has ended (Linux, from /proc).
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterable, Iterator

PR_SET_PDEATHSIG = 1  # linux/prctl.h
PARENT_POLL_S = 0.5
STOP_SIGNALS = tuple(getattr(signal, name) for name in ("SIGTERM", "SIGHUP") if hasattr(signal, name))
TERMINATE_GRACE_S = 3.0


class Stopped(KeyboardInterrupt):
    """A stop signal (SIGTERM, SIGHUP) arrived; `signum` says which. A KeyboardInterrupt, so every
    handler of Ctrl-C handles it too."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = signum

    def __str__(self) -> str:
        return f"stopped by {signal.Signals(self.signum).name}"


def _kill_me_with_parent() -> bool:
    """Ask the Linux kernel to SIGKILL this process when its parent exits; False elsewhere."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        return libc.prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0) == 0
    except (OSError, AttributeError):
        return False


def die_with_parent(parent_pid: int) -> None:
    """End this process when the process `parent_pid` (its parent) ends (module docstring)."""
    by_kernel = _kill_me_with_parent()
    if os.getppid() != parent_pid:  # the parent died before the kernel was asked
        os._exit(1)
    if not by_kernel:
        threading.Thread(target=_watch_parent, args=(parent_pid,), daemon=True,
                         name="dotsim-parent-watch").start()


def _watch_parent(parent_pid: int) -> None:
    while os.getppid() == parent_pid:
        time.sleep(PARENT_POLL_S)
    os._exit(1)


def exec_dies_with_parent() -> None:
    """subprocess preexec_fn: the child (and the program it executes) is killed when its parent
    ends (Linux; elsewhere nothing)."""
    _kill_me_with_parent()


@contextlib.contextmanager
def stop_signals() -> Iterator[None]:
    """Within the block, SIGTERM and SIGHUP raise Stopped in the main thread (elsewhere: no change)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def stop(signum, frame):
        raise Stopped(signum)

    previous = {signum: signal.signal(signum, stop) for signum in STOP_SIGNALS}
    try:
        yield
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)


def stop_processes(processes: Iterable, grace_s: float = TERMINATE_GRACE_S) -> None:
    """Terminate multiprocessing processes, then kill those still alive after grace_s seconds."""
    processes = [p for p in processes if p.is_alive()]
    for process in processes:
        process.terminate()
    deadline = time.monotonic() + grace_s
    for process in processes:
        process.join(max(0.0, deadline - time.monotonic()))
        if process.is_alive():
            process.kill()
            process.join(1.0)


def _stat_fields(pid: int) -> list[str] | None:
    """The fields of /proc/PID/stat after the command name (state first), or None (no such process,
    or not Linux)."""
    try:
        text = open(f"/proc/{pid}/stat").read()
    except OSError:
        return None
    return text[text.rindex(")") + 2:].split()


def process_status(pid: int) -> tuple[int, int] | None:
    """(parent pid, start time in clock ticks) of a live, non-zombie process, or None."""
    fields = _stat_fields(pid)
    return None if fields is None or fields[0] == "Z" else (int(fields[1]), int(fields[19]))


def is_zombie(pid: int) -> bool:
    """True for a process that has ended and is not yet reaped (it runs and writes nothing): after a
    kill -9, a worker re-parented to an init that reaps slowly stays one for a while (Linux)."""
    fields = _stat_fields(pid)
    return fields is not None and fields[0] == "Z"


def process_tree(pid: int) -> dict[int, int]:
    """pid -> start time of every live process below `pid` (Linux /proc)."""
    children: dict[int, list[tuple[int, int]]] = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit() and (stat := process_status(int(entry))):
            children.setdefault(stat[0], []).append((int(entry), stat[1]))
    found, todo = {}, [pid]
    while todo:
        for child, start in children.get(todo.pop(), []):
            if child not in found:
                found[child] = start
                todo.append(child)
    return found


def kill_tree_when_gone(pid: int) -> subprocess.Popen | None:
    """Start a watcher that kills every process below `pid` once `pid` has ended (its parent: call it
    with os.getpid()); None off Linux. Stop the watcher (kill()) once the tree was shut down in order."""
    if not sys.platform.startswith("linux"):
        return None
    package_root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [package_root,
                                                                     os.environ.get("PYTHONPATH")]))}
    return subprocess.Popen([sys.executable, "-c", f"from dotsim.process_lifetime import _watch_tree; "
                             f"_watch_tree({pid})"], env=env, start_new_session=True,
                            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def _watch_tree(pid: int) -> None:
    known: dict[int, int] = {}
    while os.getppid() == pid:  # re-parented: `pid` ended
        known.update(process_tree(pid))
        known.pop(os.getpid(), None)
        time.sleep(PARENT_POLL_S)
    for child, start in known.items():
        stat = process_status(child)
        if stat is not None and stat[1] == start:  # the same process, not a new one with its pid
            with contextlib.suppress(ProcessLookupError):
                os.kill(child, signal.SIGKILL)
