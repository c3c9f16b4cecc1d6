"""Figures written by :class:`stictiondiag.plotting.writer.FigureWriter`.

The worker processes are forked only from a single-threaded process; the test process
itself may run BLAS or other threads, so the forking cases run in a fresh
interpreter with the ``stiction`` command's environment.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from stictiondiag.errors import UsageError
from stictiondiag.plotting._fast import new_figure
from stictiondiag.plotting.writer import FigureWriter, _shares, available_workers


def _figure(k: int):
    fig, axes = new_figure(1, 1, (3, 2))
    axes[0, 0].plot(np.arange(10.0), np.arange(10.0) ** k)
    axes[0, 0].set_title(f"power {k}")
    return fig


def _direct(path: Path, k: int) -> bytes:
    _figure(k).savefig(path, dpi=110, format="png")
    return path.read_bytes()


def test_shares_keep_order_and_sizes():
    jobs = list(range(7))
    assert _shares(jobs, 3) == [[0, 1, 2], [3, 4], [5, 6]]
    assert _shares(jobs, 1) == [jobs]
    assert _shares(jobs[:2], 5) == [[0], [1]]


def test_without_workers_writes_in_order_the_same_bytes(tmp_path):
    writer = FigureWriter(tmp_path / "out", workers=0)
    for k in (1, 2, 3):
        writer.add(f"f{k}.png", lambda k=k: _figure(k))
    writer.start()  # nothing to hand out without workers
    assert not (tmp_path / "out").exists()
    written = writer.finish()
    assert written == [tmp_path / "out" / f"f{k}.png" for k in (1, 2, 3)]
    for k in (1, 2, 3):
        assert (tmp_path / "out" / f"f{k}.png").read_bytes() == _direct(tmp_path / f"d{k}.png", k)


def test_without_workers_the_first_error_propagates(tmp_path):
    def boom():
        raise ValueError("cannot build")

    writer = FigureWriter(tmp_path, workers=0)
    writer.add("a.png", lambda: _figure(1))
    writer.add("b.png", boom)
    writer.add("c.png", lambda: _figure(2))
    with pytest.raises(ValueError, match="cannot build"):
        writer.finish()
    # As a loop over the figures: the ones before are written, none after.
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.png"]


def test_unwritable_folder_is_a_usage_error(tmp_path):
    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    writer = FigureWriter(blocker, workers=0)
    writer.add("a.png", lambda: _figure(1))
    with pytest.raises(UsageError, match="cannot write"):
        writer.finish()
    assert blocker.read_text() == "x"


_SCRIPT = textwrap.dedent(
    """
    import json, os, sys
    from pathlib import Path

    import numpy as np

    from stictiondiag.errors import UsageError
    from stictiondiag.plotting._fast import new_figure
    from stictiondiag.plotting.writer import FigureWriter, _single_threaded

    out = Path(sys.argv[1])
    parent = os.getpid()
    report = {"single_threaded": _single_threaded()}

    def figure(k, log):
        def build():
            with open(out / f"pid_{log}", "w") as fh:
                fh.write(str(os.getpid()))
            fig, axes = new_figure(1, 1, (3, 2))
            axes[0, 0].plot(np.arange(10.0), np.arange(10.0) ** k)
            axes[0, 0].set_title(f"power {k}")
            return fig
        return build

    # 1. Figures handed out before other work, then the rest shared at the end.
    w = FigureWriter(out / "a", workers=1)
    w.add("f1.png", figure(1, "f1"))
    w.add("f2.png", figure(2, "f2"))
    w.start()
    w.add("f3.png", figure(3, "f3"))
    w.add("f4.png", figure(4, "f4"))
    written = w.finish()
    report["written"] = [p.name for p in written]
    report["pids"] = {k: int((out / f"pid_{k}").read_text()) != parent for k in ("f1", "f2", "f3", "f4")}

    # 2. An error in a worker reaches the caller, with the worker's traceback.
    def boom():
        raise ValueError("cannot build in the worker")
    w = FigureWriter(out / "b", workers=1)
    w.add("bad.png", boom)
    w.start()
    w.add("good.png", figure(1, "good"))
    try:
        w.finish()
    except ValueError as exc:
        report["error"] = str(exc)
        report["note"] = "in a worker process" in "".join(getattr(exc, "__notes__", []))
    report["b_files"] = sorted(p.name for p in (out / "b").iterdir())

    # 3. A worker that dies without reporting: its figures are drawn here.
    def dies():
        if os.getpid() != parent:
            os._exit(3)
        return figure(5, "dies")()
    w = FigureWriter(out / "c", workers=1)
    w.add("dies.png", dies)
    w.start()
    report["c_written"] = [p.name for p in w.finish()]

    # 4. A usage error in a worker keeps its class.
    (out / "blocker").write_text("x")
    w = FigureWriter(out / "blocker", workers=1)
    w.add("x.png", figure(1, "x"))
    w.start()
    try:
        w.finish()
    except UsageError as exc:
        report["usage_error"] = str(exc)

    # 5. An exception in the caller's block stops the workers and leaves no
    #    temporary file behind.
    def slow():
        import time
        time.sleep(30)
    try:
        with FigureWriter(out / "d", workers=1) as w:
            w.add("slow.png", slow)
            w.start()
            raise KeyboardInterrupt
    except KeyboardInterrupt:
        pass
    report["d_files"] = sorted(p.name for p in (out / "d").iterdir()) if (out / "d").exists() else []
    try:
        report["children_left"] = os.waitpid(-1, os.WNOHANG) != (0, 0)
    except ChildProcessError:
        report["children_left"] = False
    print(json.dumps(report))
    """
)


@pytest.mark.skipif(available_workers() == 0, reason="workers need Linux and two CPUs")
def test_workers_write_the_figures_and_report_errors(tmp_path):
    env = dict(os.environ)
    env.update({"OPENBLAS_NUM_THREADS": "1", "JE_ARROW_MALLOC_CONF": "background_thread:false"})
    proc = subprocess.run(
        [sys.executable, "-c", _SCRIPT, str(tmp_path)],
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
        check=False,
    )
    assert proc.returncode == 0, proc.stderr
    report = json.loads(proc.stdout.strip().splitlines()[-1])
    if not report["single_threaded"]:
        pytest.skip("the interpreter runs threads: no workers")
    assert report["written"] == ["f1.png", "f2.png", "f3.png", "f4.png"]
    # The figures handed out at start() are drawn by a worker, the last one here.
    assert report["pids"]["f1"] and report["pids"]["f2"] and not report["pids"]["f4"]
    for k in (1, 2, 3, 4):
        assert (tmp_path / "a" / f"f{k}.png").read_bytes() == _direct(tmp_path / f"d{k}.png", k)
    assert report["error"] == "cannot build in the worker" and report["note"]
    assert report["b_files"] == ["good.png"]
    assert report["c_written"] == ["dies.png"]
    assert (tmp_path / "c" / "dies.png").read_bytes() == _direct(tmp_path / "d5.png", 5)
    assert "cannot write" in report["usage_error"]
    assert report["d_files"] == []
    assert not report["children_left"]
