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

from stictiondiag.core.errors import UsageError
from stictiondiag.plotting._fast import new_figure
from stictiondiag.plotting.writer import (
    FigureWriter,
    _shares,
    available_workers,
)


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

    from stictiondiag.core.errors import UsageError
    from stictiondiag.plotting._fast import new_figure
    from stictiondiag.plotting.writer import (
        FigureWriter,
        _single_threaded,
    )

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
    import gc
    report["frozen_after"] = gc.get_freeze_count()
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
    assert report["frozen_after"] == 0  # the collector sees every object again
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


def test_pending_without_workers_computes_here_once():
    calls = []

    def value():
        calls.append(os.getpid())
        return {"x": 1.5}

    writer = FigureWriter(Path("."), workers=0)
    pending = writer.compute(value)
    writer.start()
    assert pending.stand_in().get("x") == 1.5  # attribute of the value (dict.get)
    assert pending.get() == {"x": 1.5}
    assert calls == [os.getpid()]
    assert writer.finish() == []


def test_pending_error_is_raised_by_get_and_skips_the_figures_that_need_it(tmp_path):
    from stictiondiag.plotting.writer import DependencyFailed

    def value():
        raise UsageError("no value")

    writer = FigureWriter(tmp_path, workers=0)
    pending = writer.compute(value)
    writer.add("needs.png", lambda: pending.stand_in().figure())
    writer.add("other.png", lambda: _figure(1))
    with pytest.raises(UsageError, match="no value"):
        pending.get()
    with pytest.raises(DependencyFailed):
        pending.value_for_dependents()
    assert writer.finish() == [tmp_path / "other.png"]


_SCRIPT_PENDING = textwrap.dedent(
    """
    import json, os, sys
    from pathlib import Path

    from stictiondiag.core.errors import DataError
    from stictiondiag.plotting.writer import FigureWriter

    out = Path(sys.argv[1])
    parent = os.getpid()
    report = {}

    # A value computed by the worker, which then draws a figure from it.
    class Value:
        def __init__(self):
            self.pid = os.getpid()
            self.k = 3
        def figure(self):
            from stictiondiag.plotting._fast import new_figure
            fig, axes = new_figure(1, 1, (3, 2))
            axes[0, 0].plot([0, 1, 2], [0, self.k, 1])
            return fig

    w = FigureWriter(out / "a", workers=1)
    p = w.compute(Value)
    w.add("v.png", lambda: p.stand_in().figure())
    w.start()
    v = p.get()
    report["value_from_worker"] = v.pid != parent and v.k == 3
    report["written"] = [q.name for q in w.finish()]

    # The function's exception comes back with its class; the figure needing the
    # value is left out, the others are drawn.
    def fails():
        raise DataError("nothing to replay")
    w = FigureWriter(out / "b", workers=1)
    p = w.compute(fails)
    w.add("needs.png", lambda: p.stand_in().figure())
    w.add("free.png", lambda: Value().figure())
    w.start()
    try:
        p.get()
    except DataError as exc:
        report["error"] = str(exc)
    report["b_written"] = [q.name for q in w.finish()]

    # A worker that dies before delivering: the value is computed here.
    def dies():
        if os.getpid() != parent:
            os._exit(3)
        return "here"
    w = FigureWriter(out / "c", workers=1)
    p = w.compute(dies)
    w.start()
    report["after_death"] = p.get()
    w.finish()

    # A value that cannot be pickled is computed here too.
    def unpicklable():
        return (os.getpid(), lambda: None)
    w = FigureWriter(out / "d", workers=1)
    p = w.compute(unpicklable)
    w.start()
    report["unpicklable_here"] = p.get()[0] == parent
    w.finish()
    print(json.dumps(report))
    """
)


def _run_single_threaded(script: str, *args: str) -> dict:
    env = dict(os.environ)
    env.update({"OPENBLAS_NUM_THREADS": "1", "JE_ARROW_MALLOC_CONF": "background_thread:false"})
    proc = subprocess.run(
        [sys.executable, "-c", script, *args],
        capture_output=True,
        text=True,
        env=env,
        timeout=600,
        check=False,
    )
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout.strip().splitlines()[-1])


@pytest.mark.skipif(available_workers() == 0, reason="workers need Linux and two CPUs")
def test_values_computed_by_a_worker(tmp_path):
    report = _run_single_threaded(_SCRIPT_PENDING, str(tmp_path))
    assert report["value_from_worker"]
    assert report["written"] == ["v.png"]
    assert report["error"] == "nothing to replay"
    assert report["b_written"] == ["free.png"]
    assert report["after_death"] == "here"
    assert report["unpicklable_here"]


_SCRIPT_SERVING = textwrap.dedent(
    """
    import functools, json, os, sys
    from pathlib import Path

    import numpy as np

    from stictiondiag.core.errors import DataError
    from stictiondiag.plotting.writer import (
        FigureWriter,
        _single_threaded,
    )

    out = Path(sys.argv[1])
    parent = os.getpid()
    report = {"single_threaded": _single_threaded()}

    # Module-level functions bound with functools.partial: picklable, so that work
    # added after a worker started can be sent to it.
    def figure(k, log):
        (out / f"pid_{log}").write_text(str(os.getpid()))
        if log == "dies" and os.getpid() != parent:
            os._exit(3)
        from stictiondiag.plotting._fast import new_figure
        fig, axes = new_figure(1, 1, (3, 2))
        axes[0, 0].plot(np.arange(10.0), np.arange(10.0) ** k)
        axes[0, 0].set_title(f"power {k}")
        return fig

    def prepare():
        import matplotlib.figure  # noqa: F401
        (out / "prepared").write_text(str(os.getpid()))

    def value(x):
        return {"pid": os.getpid(), "x": x}

    def fails():
        raise DataError("no value here")

    # 1. A worker started early: it computes the value queued before it, prepares,
    #    computes a value sent later and draws a figure sent later; the figures of
    #    finish() are drawn by it and a fork of it, none here.
    w = FigureWriter(out / "a", workers=1)
    first = w.compute(functools.partial(value, 1))
    report["warm"] = w.warm_up(prepare)
    report["warm_again"] = w.warm_up(prepare)
    v1 = first.get()
    later = w.compute(functools.partial(value, 2))
    bad = w.compute(fails)
    w.add("f1.png", functools.partial(figure, 1, "f1"))
    w.start()
    v2 = later.get()
    try:
        bad.get()
    except DataError as exc:
        report["error"] = str(exc)
    w.add("f2.png", functools.partial(figure, 2, "f2"))
    w.add("f3.png", functools.partial(figure, 3, "f3"))
    report["written"] = [p.name for p in w.finish()]
    pid = {k: int((out / f"pid_{k}").read_text()) for k in ("f1", "f2", "f3")}
    worker = int((out / "prepared").read_text())
    report["values"] = [v1["pid"] == worker, v2["pid"] == worker, v1["x"], v2["x"]]
    report["f1_by_worker"] = pid["f1"] == worker
    report["f2_f3_side_by_side"] = len({pid["f2"], pid["f3"], parent}) == 3
    report["no_matplotlib_here"] = "matplotlib" not in sys.modules

    # 2. A worker that dies with work sent to it: the figures are drawn here.
    w = FigureWriter(out / "b", workers=1)
    w.warm_up()
    w.add("dies.png", functools.partial(figure, 4, "dies"))
    w.add("lives.png", functools.partial(figure, 5, "lives"))
    report["b_written"] = [p.name for p in w.finish()]

    # 3. Work that cannot be pickled does not go to a waiting worker: drawn here.
    w = FigureWriter(out / "c", workers=1)
    w.warm_up()
    w.add("lambda.png", lambda: figure(6, "lambda"))
    report["c_written"] = [p.name for p in w.finish()]
    report["c_here"] = int((out / "pid_lambda").read_text()) == parent
    try:
        report["children_left"] = os.waitpid(-1, os.WNOHANG) != (0, 0)
    except ChildProcessError:
        report["children_left"] = False
    print(json.dumps(report))
    """
)


@pytest.mark.skipif(available_workers() == 0, reason="workers need Linux and two CPUs")
def test_a_worker_started_early_takes_later_work(tmp_path):
    report = _run_single_threaded(_SCRIPT_SERVING, str(tmp_path))
    if not report["single_threaded"]:
        pytest.skip("the interpreter runs threads: no workers")
    assert report["warm"] and not report["warm_again"]
    assert report["values"] == [True, True, 1, 2]
    assert report["error"] == "no value here"
    assert report["written"] == ["f1.png", "f2.png", "f3.png"]
    assert report["f1_by_worker"] and report["f2_f3_side_by_side"]
    assert report["no_matplotlib_here"]
    for k in (1, 2, 3):
        assert (tmp_path / "a" / f"f{k}.png").read_bytes() == _direct(tmp_path / f"d{k}.png", k)
    assert report["b_written"] == ["dies.png", "lives.png"]
    assert (tmp_path / "b" / "dies.png").read_bytes() == _direct(tmp_path / "d4.png", 4)
    assert report["c_written"] == ["lambda.png"] and report["c_here"]
    assert not report["children_left"]


_SCRIPT_ANALYSIS = textwrap.dedent(
    """
    import json, os, sys
    from pathlib import Path

    from stictiondiag.replay import closed_loop as replay_module
    from stictiondiag.analysis import analyze
    from stictiondiag.core.errors import DataError
    from stictiondiag.models.loops import simulate_loop
    from stictiondiag.plotting.writer import (
        FigureWriter,
        _single_threaded,
    )
    from stictiondiag.models.processes import LOOP_PARAMETERS
    from stictiondiag.io.tags import Tags

    out = Path(sys.argv[1])
    loop = LOOP_PARAMETERS["concentration"]
    sim = simulate_loop(loop["process"], loop["controller"], duration=3000.0, dt=1.0,
                        S=5.0, J=2.0, noise_std=0.05, seed=3)
    keep = slice(500, None)
    tags = Tags.from_arrays(sim.pv[keep], sim.op[keep], mv=sim.mv[keep], sp=sim.sp[keep],
                            ts=1.0)
    report = {"single_threaded": _single_threaded()}

    def run(folder):
        with FigureWriter(out / folder) as w:
            report[folder + "_worker"] = w.can_start()
            a = analyze(tags, figures=w)
            written = [p.name for p in w.finish()]
        return a, written

    # The replay in a worker beside the gap diagnosis: the result of the steps one
    # after the other, and every figure.
    a, written = run("both")
    plain = analyze(tags)
    report["same_result"] = a.to_dict() == plain.to_dict()
    report["written"] = written
    for name, fig in plain.figures().items():
        fig.savefig(out / f"plain_{name}.png", dpi=110, format="png")

    # From a file: the worker reads it while this process sets up the analysis.
    from stictiondiag.analysis import analyze_file
    from stictiondiag.core.errors import StictionError

    csv = out / "loop.csv"
    tags.to_pandas().to_csv(csv, index=False)
    with FigureWriter(out / "file") as w:
        a = analyze_file(csv, figures=w)
        report["file_written"] = [p.name for p in w.finish()]
    report["file_same"] = a.to_dict() == analyze_file(csv).to_dict()
    (out / "bad.csv").write_text("a,b\\n1,2\\n")
    errors = []
    for figures in (FigureWriter(out / "bad"), None):
        try:
            analyze_file(out / "bad.csv", figures=figures)
        except StictionError as exc:
            errors.append((type(exc).__name__, str(exc)))
        if figures is not None:
            figures.stop()
    report["bad_same_error"] = len(errors) == 2 and errors[0] == errors[1]

    # A replay that is not possible: no gap diagnosis, a warning, no reconstruction.
    def no_replay(*args, **kwargs):
        raise DataError("no replay here")
    replay_module.replay = no_replay
    a, written = run("no_replay")
    plain = analyze(tags)
    report["no_replay_same"] = a.to_dict() == plain.to_dict()
    report["no_replay_warnings"] = [w for w in a.warnings if "replay" in w]
    report["no_replay_gap"] = a.gap is None
    report["no_replay_written"] = written

    # A replay that fails unexpectedly: the error reaches the caller.
    def broken(*args, **kwargs):
        raise ZeroDivisionError("broken replay")
    replay_module.replay = broken
    try:
        run("broken")
    except ZeroDivisionError as exc:
        report["broken"] = str(exc)
    print(json.dumps(report))
    """
)


@pytest.mark.skipif(available_workers() == 0, reason="workers need Linux and two CPUs")
def test_analysis_with_the_replay_in_a_worker(tmp_path):
    report = _run_single_threaded(_SCRIPT_ANALYSIS, str(tmp_path))
    if not report["single_threaded"]:
        pytest.skip("the interpreter runs threads: no workers")
    assert report["both_worker"]
    assert report["same_result"]
    names = ["phase", "reconstruction", "gap_breakdown", "gap_replay"]
    assert report["written"] == [f"<memory>_{n}.png" for n in names]
    for n in names:
        assert (tmp_path / "both" / f"<memory>_{n}.png").read_bytes() == (
            tmp_path / f"plain_{n}.png"
        ).read_bytes(), n
    assert report["file_same"] and report["bad_same_error"]
    assert report["file_written"] == [f"loop_{n}.png" for n in names]
    assert report["no_replay_same"]
    assert report["no_replay_warnings"] == ["replay not possible: no replay here"]
    assert report["no_replay_gap"]
    assert report["no_replay_written"] == ["<memory>_phase.png"]
    assert report["broken"] == "broken replay"
