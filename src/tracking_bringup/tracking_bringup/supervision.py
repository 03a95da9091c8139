"""Process supervision of the launcher: what a process is (:class:`ProcessSpec`), starting one
with its own log file and bound to the launcher (PR_SET_PDEATHSIG, so none is orphaned),
stopping it (SIGINT, then SIGTERM, then SIGKILL; a frozen one is killed at once) and the error
of one that died (:func:`death`: exit code 2 is a refused parameter or input, named in the
node's one ``error:`` line). The order in which a graph's processes stop is
:class:`tracking_bringup.launcher.GraphLauncher`'s.
"""

from __future__ import annotations

import contextlib
import ctypes
import signal
import subprocess
import time
from dataclasses import dataclass, field
from pathlib import Path

_PR_SET_PDEATHSIG = 1
CLEAN_EXIT_CODES = {0, -signal.SIGINT, 128 + signal.SIGINT, -signal.SIGTERM, 128 + signal.SIGTERM}


#: a node's (and the launcher's) exit code for a bad parameter, argument or input file
EXIT_BAD_INPUT = 2


class LaunchError(RuntimeError):
    """The graph could not be started, or a node died. ``node`` names it when known;
    ``exit_code`` is the launcher's: 1, or 2 when the node refused its parameters or input
    (it exited with code 2 and said why in one line)."""

    def __init__(self, message: str, node: str | None = None, exit_code: int = 1):
        super().__init__(message)
        self.node = node
        self.exit_code = exit_code


class LaunchInterrupted(LaunchError):
    """A stop was requested (Ctrl-C, SIGTERM) before the graph was ready."""


@dataclass
class ProcessSpec:
    """One process to run: its name (the ROS node name), command line and graph role."""

    name: str
    argv: list[str]
    subscribes: tuple[str, ...] = ()
    publishes: tuple[str, ...] = ()
    source: bool = False
    finishes: bool = False
    namespace: str = ""  # the node's ROS namespace ("" or "/rig2")


@dataclass
class Running:
    """One started process: its spec, ``Popen`` and log file."""

    spec: ProcessSpec
    proc: subprocess.Popen
    log_path: Path
    log_file: object = field(repr=False)


def _bind_to_parent() -> None:
    """In the child before exec: die with SIGTERM when the launcher dies (Linux)."""
    try:
        libc = ctypes.CDLL("libc.so.6", use_errno=True)
        libc.prctl(_PR_SET_PDEATHSIG, signal.SIGTERM)
    except OSError:
        pass


def spawn(spec: ProcessSpec, log_dir: Path, env: dict[str, str], echo: bool) -> Running:
    """Start one process, its output in ``log_dir/<name>.log`` (on the console with ``echo``)."""
    log_path = log_dir / f"{spec.name}.log"
    # this run's log only: a death report never quotes an earlier run's lines
    log_file = open(log_path, "wb", buffering=0)  # noqa: SIM115 (closed in shutdown)
    log_file.write(f"$ {' '.join(spec.argv)}\n".encode())
    proc = subprocess.Popen(
        spec.argv,
        stdin=subprocess.DEVNULL,
        stdout=None if echo else log_file,
        stderr=subprocess.STDOUT if not echo else None,
        env=env,
        start_new_session=True,  # Ctrl-C reaches the launcher only; it stops the children
        preexec_fn=_bind_to_parent,
    )
    return Running(spec, proc, log_path, log_file)


def stop(run: Running, stop_timeout: float, frozen: bool = False) -> int:
    """Stop one process and return its exit code: SIGINT (``stop_timeout`` s), SIGTERM, then
    SIGKILL; a ``frozen`` one (stalled) is killed at once."""
    proc = run.proc
    if proc.poll() is not None:
        return proc.returncode
    if frozen:  # a frozen process takes no SIGINT: no drain
        with contextlib.suppress(ProcessLookupError):
            proc.kill()
        return proc.wait()
    for sig, timeout in (
        (signal.SIGINT, stop_timeout),
        (signal.SIGTERM, 5.0),
        (signal.SIGKILL, 5.0),
    ):
        try:
            proc.send_signal(sig)
        except ProcessLookupError:
            break
        try:
            return proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            continue
    return proc.wait()


def stop_all(runs: list[Running], stop_timeout: float) -> dict[str, int]:
    """Stop processes at once (start-up interrupted): SIGTERM to all, then SIGKILL."""
    for sig, timeout in ((signal.SIGTERM, stop_timeout), (signal.SIGKILL, 5.0)):
        alive = [r for r in runs if r.proc.poll() is None]
        for run in alive:
            with contextlib.suppress(ProcessLookupError):
                run.proc.send_signal(sig)
        deadline = time.monotonic() + timeout
        for run in alive:
            with contextlib.suppress(subprocess.TimeoutExpired):
                run.proc.wait(timeout=max(0.0, deadline - time.monotonic()))
    return {r.spec.name: r.proc.wait() for r in runs}


def death(run: Running, code: int, what: str) -> LaunchError:
    """The error of a node that exited: with code 2 (a bad parameter or input, which the node
    named in one ``error:`` line) that line, and the launcher exits 2; else the node, its
    exit code and the end of its log, and the launcher exits 1."""
    name = run.spec.name
    line = _error_line(run.log_path)
    if code == EXIT_BAD_INPUT and line:
        return LaunchError(line.removeprefix("error: "), node=name, exit_code=EXIT_BAD_INPUT)
    reason = f": {line.removeprefix('error: ')}" if line else ""
    return LaunchError(
        f"node '{name}' {what} (exit code {code}){reason}; log: {run.log_path}\n"
        + _tail(run.log_path),
        node=name,
    )


def _error_line(path: Path) -> str | None:
    """The last ``error: ...`` line of a node's log (its one-line reason for exit code 2)."""
    try:
        lines = path.read_text(errors="replace").splitlines()
    except OSError:
        return None
    found = [line.strip() for line in lines if line.startswith("error: ")]
    return found[-1] if found else None


def _tail(path: Path, lines: int = 15) -> str:
    try:
        text = path.read_text(errors="replace").splitlines()
    except OSError:
        return ""
    return "\n".join("    " + line for line in text[-lines:])
