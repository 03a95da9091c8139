"""Process supervision (tracking_bringup.supervision): one process started with its own log,
stopped by signals in turn, and the error of one that died."""

import signal
import sys
import time

from tracking_bringup.supervision import (
    CLEAN_EXIT_CODES,
    EXIT_BAD_INPUT,
    ProcessSpec,
    death,
    spawn,
    stop,
    stop_all,
)

# a process that ignores SIGINT and SIGTERM: only SIGKILL stops it
STUBBORN = (
    "import signal, sys, time\n"
    "signal.signal(signal.SIGINT, signal.SIG_IGN)\n"
    "signal.signal(signal.SIGTERM, signal.SIG_IGN)\n"
    "print('ready', flush=True)\n"
    "time.sleep(60)\n"
)


def _started(run):
    """Wait until the child printed 'ready' (its signal handlers are set; the log's first line,
    its command, holds the word too)."""
    deadline = time.monotonic() + 30
    while b"\nready\n" not in run.log_path.read_bytes() and time.monotonic() < deadline:
        time.sleep(0.02)


SLEEPER = "import time; time.sleep(60)"


def _spawn(tmp_path, name, code):
    return spawn(ProcessSpec(name, [sys.executable, "-c", code]), tmp_path, None, False)


def _end(*runs):
    for run in runs:
        run.proc.kill()
        run.proc.wait(10)
        run.log_file.close()


def test_spawn_writes_the_command_and_output_to_the_nodes_log(tmp_path):
    spec = ProcessSpec("hello", [sys.executable, "-c", "print('hello from the node')"])
    run = spawn(spec, tmp_path, env=None, echo=False)
    try:
        assert run.proc.wait(30) == 0
    finally:
        run.log_file.close()
    text = (tmp_path / "hello.log").read_text()
    assert text.startswith(f"$ {sys.executable} -c")
    assert "hello from the node" in text


def test_stop_sends_sigint_first_and_kills_a_stubborn_or_frozen_process(tmp_path):
    polite = _spawn(tmp_path, "p", SLEEPER)
    stubborn = _spawn(tmp_path, "s", STUBBORN)
    frozen = _spawn(tmp_path, "f", STUBBORN)
    try:
        _started(stubborn)
        _started(frozen)
        assert stop(polite, stop_timeout=10.0) in CLEAN_EXIT_CODES  # KeyboardInterrupt
        assert stop(stubborn, stop_timeout=0.2) == -signal.SIGKILL  # SIGINT, SIGTERM ignored
        t0 = time.monotonic()
        assert stop(frozen, stop_timeout=30.0, frozen=True) == -signal.SIGKILL  # at once
        assert time.monotonic() - t0 < 5.0
        assert stop(polite, stop_timeout=10.0) == polite.proc.returncode  # already gone
    finally:
        _end(polite, stubborn, frozen)


def test_stop_all_terminates_every_process_at_once(tmp_path):
    runs = [_spawn(tmp_path, n, SLEEPER) for n in ("a", "b")]
    stubborn = _spawn(tmp_path, "s", STUBBORN)
    try:
        _started(stubborn)
        codes = stop_all([*runs, stubborn], stop_timeout=0.5)
        assert codes == {"a": -signal.SIGTERM, "b": -signal.SIGTERM, "s": -signal.SIGKILL}
    finally:
        _end(*runs, stubborn)


def test_death_quotes_the_nodes_error_line_or_its_log(tmp_path):
    refusing = _spawn(tmp_path, "r", "print('error: parameter x: bad'); exit(2)")
    crashing = _spawn(tmp_path, "c", "print('line one'); exit(3)")
    for run in (refusing, crashing):
        run.proc.wait(30)
        run.log_file.close()
    err = death(refusing, 2, "died")
    assert (str(err), err.node, err.exit_code) == ("parameter x: bad", "r", EXIT_BAD_INPUT)
    err = death(crashing, 3, "died during start-up")
    assert str(err).startswith("node 'c' died during start-up (exit code 3); log: ")
    assert "    line one" in str(err) and err.exit_code == 1
