"""Nothing left running: SIGTERM takes Ctrl-C's path, workers end with their parent.

Each test runs the real ``stiction`` command in a subprocess with two worker
processes, waits until the workers exist, signals the command and then checks, by
process id, that no worker is left.  Linux only (the process table is read from
``/proc``).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = ROOT / "sample_data"
STICTION = Path(sys.executable).with_name("stiction")

pytestmark = pytest.mark.skipif(
    not Path("/proc/self/stat").exists() or not STICTION.exists(),
    reason="needs /proc and the stiction console script",
)


def _children(pid: int) -> set[int]:
    """Process ids whose parent is ``pid``."""
    found = set()
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            stat = Path(f"/proc/{entry}/stat").read_text()
        except OSError:
            continue
        # Fields after the command name (which may hold spaces) in parentheses.
        fields = stat.rsplit(")", 1)[1].split()
        if fields[0] != "Z" and int(fields[1]) == pid:
            found.add(int(entry))
    return found


def _alive(pids: set[int]) -> set[int]:
    alive = set()
    for pid in pids:
        try:
            state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
        except OSError:
            continue
        if state != "Z":
            alive.add(pid)
    return alive


def _start_report(tmp_path: Path) -> tuple[subprocess.Popen, set[int]]:
    """``stiction report`` over four loops on two workers, once both workers run."""
    env = dict(os.environ)
    files = [SAMPLES / f for f in ("healthy_flow.csv", "slave_flow_stickslip.csv")] * 2
    inputs = []
    for i, f in enumerate(files):
        inputs.append(tmp_path / f"loop{i}.csv")
        inputs[-1].write_bytes(f.read_bytes())
    proc = subprocess.Popen(
        [
            str(STICTION),
            "report",
            *map(str, inputs),
            "--out",
            str(tmp_path / "r"),
            "--workers",
            "2",
            "--no-gap",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        cwd=tmp_path,
    )
    deadline = time.monotonic() + 60
    workers: set[int] = set()
    while time.monotonic() < deadline and proc.poll() is None:
        # The pool's workers (and multiprocessing's resource tracker) are children.
        workers = _children(proc.pid)
        if len(workers) >= 2:
            break
        time.sleep(0.1)
    assert proc.poll() is None and len(workers) >= 2, "the workers never started"
    time.sleep(1.0)  # let them import and take a loop each
    return proc, _children(proc.pid)


def _wait_gone(pids: set[int], seconds: float) -> set[int]:
    deadline = time.monotonic() + seconds
    while _alive(pids) and time.monotonic() < deadline:
        time.sleep(0.1)
    return _alive(pids)


def test_sigterm_stops_the_pool_prints_one_line_and_exits_143(tmp_path):
    proc, workers = _start_report(tmp_path)
    proc.send_signal(signal.SIGTERM)
    _, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 143, stderr
    assert stderr.rstrip().splitlines()[-1] == "stiction: terminated"
    assert "Traceback" not in stderr
    # The main process stopped its workers before it exited.
    assert _wait_gone(workers, 5.0) == set()


def test_workers_end_when_their_parent_is_killed(tmp_path):
    proc, workers = _start_report(tmp_path)
    proc.send_signal(signal.SIGKILL)  # no clean-up possible in the parent
    proc.communicate(timeout=30)
    # Each worker notices within its poll interval (0.5 s) and ends itself.
    left = _wait_gone(workers, 10.0)
    for pid in left:  # do not leave them behind should the test fail
        os.kill(pid, signal.SIGKILL)
    assert left == set()


def test_dask_workers_are_capped_by_loops_and_cores_with_a_note():
    # Issue 31: 300 workers for 2 loops printed 443 tracebacks.
    from stictiondiag.apps.scan import DASK_WORKERS_PER_CORE, _pool_size

    notes: list[str] = []
    assert _pool_size("dask", None, 300, 2, notes, None) == 2
    assert "started 2 Dask workers, not 300" in notes[0]
    cap = DASK_WORKERS_PER_CORE * (os.cpu_count() or 1)
    assert _pool_size("dask", None, 300, 10_000, [], None) == min(300, cap)
    # A remote cluster's size is its own; a local pool only needs a worker per loop.
    assert _pool_size("dask", "tcp://host:8786", 300, 10_000, [], None) == 300
    assert _pool_size("local", None, 8, 3, [], None) == 3
