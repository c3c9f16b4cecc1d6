"""Plant-scale scan: discovery, engines, ranking, failures, resume, outputs, memory bound."""

from __future__ import annotations

import importlib.util
import json
import math
import os
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from stictiondiag.apps.scan import (
    VERDICT_RANK,
    LoopSource,
    analyse_source,
    discover,
    load_source,
    rank,
    run_dask,
    run_local,
    scan,
    severity,
)
from stictiondiag.core.errors import (
    DataError,
    UsageError,
)

ROOT = Path(__file__).resolve().parents[1]

# Small loops keep the file fast; the analysis of 2 000 samples is enough for a
# sticky valve's limit cycle (tens of cycles) and for the healthy loops' noise.
N_LOOPS = 8
N_SAMPLES = 2000
WORKERS = 2


def make_plant(*args, **kwargs):
    """scripts/make_plant.py, loaded on use: pool workers import this module too."""
    spec = importlib.util.spec_from_file_location("make_plant", ROOT / "scripts" / "make_plant.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.make_plant(*args, **kwargs)


@pytest.fixture(scope="module")
def plant(tmp_path_factory) -> Path:
    """Eight loops, alternating CSV and Parquet, half sticky, a quarter with mv."""
    folder = tmp_path_factory.mktemp("plant")
    make_plant(
        folder,
        N_LOOPS,
        n_samples=N_SAMPLES,
        seed=3,
        fmt="mixed",
        mv_share=0.25,
        sticky_model="simple",
    )
    return folder


@pytest.fixture(scope="module")
def local_scan(plant, tmp_path_factory):
    out = tmp_path_factory.mktemp("scan_local")
    return scan(plant, out=out, engine="local", workers=WORKERS, gap=False), out


# ----------------------------------------------------------------------------- discover


def test_discover_folder_of_csv_and_parquet_files(plant, tmp_path):
    sources = discover(plant)
    assert [s.loop for s in sources] == [f"L{i:04d}" for i in range(N_LOOPS)]
    assert all(s.loop_column is None for s in sources)
    suffixes = {Path(s.path).suffix for s in sources}
    assert suffixes == {".csv", ".parquet"}
    # truth.json sits beside the loops and is not a loop.
    assert (plant / "truth.json").exists()
    assert all(Path(s.path).parent == plant for s in sources)


def test_discover_ignores_hidden_and_marker_files(plant, tmp_path):
    for f in sorted(plant.iterdir())[:2]:
        (tmp_path / f.name).write_bytes(f.read_bytes())
    (tmp_path / "_SUCCESS").write_text("")
    (tmp_path / ".partial.csv").write_text("garbage")
    (tmp_path / "notes.txt").write_text("not a loop")
    assert [s.loop for s in discover(tmp_path)] == ["L0000", "L0001"]


def test_discover_single_file_is_one_loop(plant):
    sources = discover(plant / "L0001.parquet")
    assert sources == [LoopSource("L0001", str(plant / "L0001.parquet"))]


def _per_loop_frames(n_loops=4, n_samples=300):
    rng = np.random.default_rng(0)
    return {
        f"L{i}": pd.DataFrame(
            {
                "time": np.arange(n_samples, dtype=float),
                "pv": rng.normal(size=n_samples),
                "op": 50 + rng.normal(size=n_samples),
            }
        )
        for i in range(n_loops)
    }


def test_discover_parquet_dataset_file_with_loop_id_column(tmp_path):
    frames = _per_loop_frames()
    # Rows of different loops interleaved: the reader must filter, not slice.
    data = pd.concat([f.assign(loop_id=k) for k, f in frames.items()]).sample(
        frac=1, random_state=1
    )
    data = data.sort_values("time", kind="mergesort")
    data.to_parquet(tmp_path / "plant.parquet", index=False)
    sources = discover(tmp_path / "plant.parquet")
    assert [s.loop for s in sources] == sorted(frames)
    assert {s.loop_column for s in sources} == {"loop_id"}
    for src in sources:
        tags = load_source(src)
        # Values pass through Parquet unchanged: the loop's own rows, exactly.
        np.testing.assert_array_equal(tags.pv, frames[src.loop]["pv"].to_numpy())
    # The folder holding only that file is the same dataset.
    assert [s.loop for s in discover(tmp_path)] == sorted(frames)


def test_discover_partitioned_dataset_folder(tmp_path):
    frames = _per_loop_frames()
    table = pa.Table.from_pandas(
        pd.concat([f.assign(loop_id=k) for k, f in frames.items()]), preserve_index=False
    )
    pq.write_to_dataset(table, tmp_path / "plant", partition_cols=["loop_id"])
    (tmp_path / "plant" / "_SUCCESS").write_text("")
    assert not any(f.suffix == ".parquet" for f in (tmp_path / "plant").iterdir())
    sources = discover(tmp_path / "plant")
    assert [s.loop for s in sources] == sorted(frames)
    tags = load_source(sources[2])
    np.testing.assert_array_equal(tags.op, frames[sources[2].loop]["op"].to_numpy())


def test_discover_integer_loop_ids_and_explicit_column(tmp_path):
    frames = _per_loop_frames(3)
    data = pd.concat([f.assign(unit=100 + i) for i, f in enumerate(frames.values())])
    data.to_parquet(tmp_path / "plant.parquet", index=False)
    # "unit" is not a recognised loop-id name: without the option each file is a loop.
    assert [s.loop for s in discover(tmp_path)] == ["plant"]
    sources = discover(tmp_path, loop_column="unit")
    assert [s.loop for s in sources] == ["100", "101", "102"]
    np.testing.assert_array_equal(load_source(sources[1]).pv, frames["L1"]["pv"].to_numpy())


def test_discover_errors(tmp_path, plant):
    with pytest.raises(DataError, match="no such file"):
        discover(tmp_path / "absent")
    with pytest.raises(DataError, match="no .csv or .parquet"):
        discover(tmp_path)
    with pytest.raises(UsageError, match="applies to a Parquet dataset"):
        discover(plant, loop_column="loop_id")
    frames = _per_loop_frames(2)
    pd.concat([f.assign(loop_id=k) for k, f in frames.items()]).to_parquet(
        tmp_path / "d.parquet", index=False
    )
    with pytest.raises(UsageError, match="not in"):
        discover(tmp_path / "d.parquet", loop_column="unit")


def test_corrupt_parquet_among_loop_files_is_one_failed_loop(tmp_path, plant):
    # "A0" sorts first, so the dataset probe meets the corrupt file first.
    (tmp_path / "A0.parquet").write_bytes(b"PAR1 this is not parquet")
    (tmp_path / "L0001.parquet").write_bytes((plant / "L0001.parquet").read_bytes())
    sources = discover(tmp_path)
    assert [s.loop for s in sources] == ["A0", "L0001"]
    bad = analyse_source(sources[0], {}, False)
    assert bad["row"]["verdict"] == "error"
    assert bad["analysis"] is None
    assert "\n" not in bad["row"]["error"]


# ----------------------------------------------------------------------------- ranking


def test_rank_orders_by_verdict_then_severity():
    rows = [
        {"loop": "e", "verdict": "error", "error": "bad file"},
        {"loop": "n", "verdict": "no_stiction", "S": 0.1, "J": 0.0, "confidence": 0.9},
        {"loop": "s_small", "verdict": "stiction", "S": 1.0, "J": 0.5, "confidence": 0.9},
        {"loop": "i", "verdict": "inconclusive", "S": 8.0, "J": 4.0, "confidence": 0.5},
        {"loop": "s_big", "verdict": "stiction", "S": 4.0, "J": 2.0, "confidence": 0.8},
        {"loop": "s_nan", "verdict": "stiction", "S": float("nan"), "J": 1.0, "confidence": 0.8},
    ]
    table = rank(rows)
    assert list(table["loop"]) == ["s_big", "s_small", "s_nan", "i", "n", "e"]
    assert list(table["rank"]) == [1, 2, 3, 4, 5, 6]
    # severity = confidence x (S + J): 0.8 x 6 = 4.8 and 0.9 x 1.5 = 1.35; exact in
    # binary to a few ulps.
    assert table["severity"].iloc[0] == pytest.approx(4.8, rel=1e-12)
    assert table["severity"].iloc[1] == pytest.approx(1.35, rel=1e-12)
    assert table["severity"].iloc[2] == 0.0
    assert list(table.columns[:4]) == ["rank", "loop", "verdict", "severity"]


def test_rank_layout_does_not_depend_on_arrival_order():
    rows = [
        {"loop": "b", "source": "b.csv", "error": "x", "verdict": "error"},
        {
            "loop": "a",
            "source": "a.csv",
            "error": None,
            "verdict": "stiction",
            "S": 1.0,
            "J": 1.0,
            "confidence": 0.5,
            "zeta": 1,
        },
    ]
    pd.testing.assert_frame_equal(rank(rows), rank(rows[::-1]))


def test_severity_of_incomplete_rows_is_zero():
    assert severity({"verdict": "error"}) == 0.0
    assert severity({"S": 2.0, "J": None, "confidence": 1.0}) == 0.0
    assert severity({"S": "n/a", "J": 1.0, "confidence": 1.0}) == 0.0
    assert severity({"S": math.inf, "J": 1.0, "confidence": 1.0}) == 0.0


# ----------------------------------------------------------------------------- runners


def _die_on(item, victim):
    if item == victim:
        os._exit(13)  # a worker killed without a Python exception (OOM killer, segfault)
    if item == "raise":
        raise RuntimeError("boom\nsecond line")
    time.sleep(0.02)
    return item, os.getpid()


class _CountingIterable:
    """Counts the sources taken from it: taken minus results is the loops in flight."""

    def __init__(self, items):
        self.items = list(items)
        self.taken = 0

    def __iter__(self):
        for item in self.items:
            self.taken += 1
            yield item


def _drain(runner, todo):
    """Run to the end; return {item: "ok" or exception name}, in-flight counts, pids."""
    got, in_flight, pids = {}, [], set()
    for res in runner:
        in_flight.append(todo.taken - len(got))
        if isinstance(res[1], BaseException):
            got[res[0]] = type(res[1]).__name__
        else:
            got[res[0]] = "ok"
            pids.add(res[1])
    return got, in_flight, pids


def test_run_local_bounds_in_flight_and_survives_dead_workers():
    # Both tests in one: every pool start costs seconds (the workers import the package).
    items = [f"x{i}" for i in range(24)] + ["raise"]
    items.insert(14, "victim")
    todo = _CountingIterable(items)
    runner = run_local(todo, _die_on, ("victim",), WORKERS, on_error=lambda s, e: (s, e))
    got, in_flight, pids = _drain(runner, todo)
    assert set(got) == set(items)
    # Memory bound: never more than 2 x workers loops submitted and not yet returned,
    # and the bound is reached (the pool is kept busy, not fed one loop at a time).
    assert max(in_flight) == 2 * WORKERS
    assert len(pids) >= WORKERS and os.getpid() not in pids
    assert got["victim"] == "BrokenProcessPool"
    assert got["raise"] == "RuntimeError"
    # Loops in flight with the dead worker fail with it (at most 2 x workers); the
    # rest, on a fresh pool, succeed.
    broken = [k for k, v in got.items() if v == "BrokenProcessPool"]
    assert 1 <= len(broken) <= 2 * WORKERS
    assert sum(v == "ok" for v in got.values()) == len(items) - len(broken) - 1
    assert all(got[f"x{i}"] == "ok" for i in range(18, 24))
    # Without on_error a failure propagates.
    with pytest.raises(RuntimeError, match="boom"):
        list(run_local(["raise"], _die_on, ("victim",), 1))


def _blas_threads(item):
    return item, os.environ.get("OPENBLAS_NUM_THREADS"), os.environ.get("MKL_NUM_THREADS")


def test_run_local_workers_run_one_blas_thread(monkeypatch):
    # One worker per core and a multi-threaded BLAS in each put two threads on every
    # core: on two cores a 100-loop scan took 206 s instead of 79 s.  The workers get
    # one thread each; this process's environment is left as it was.
    for var in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        monkeypatch.delenv(var, raising=False)
    got = list(run_local(["a", "b", "c", "d"], _blas_threads, (), WORKERS))
    assert sorted(got) == [(x, "1", "1") for x in "abcd"]
    assert "OPENBLAS_NUM_THREADS" not in os.environ and "MKL_NUM_THREADS" not in os.environ
    # A value the user set is the one the workers see.
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "3")
    got = list(run_local(["a", "b"], _blas_threads, (), WORKERS))
    assert sorted(got) == [("a", "3", "1"), ("b", "3", "1")]
    assert os.environ["OPENBLAS_NUM_THREADS"] == "3" and "MKL_NUM_THREADS" not in os.environ


@pytest.fixture(scope="module")
def dask_cluster():
    distributed = pytest.importorskip("distributed")
    cluster = distributed.LocalCluster(
        n_workers=WORKERS, threads_per_worker=1, processes=True, dashboard_address=":0"
    )
    yield cluster
    cluster.close()


def test_run_dask_bounds_in_flight_and_records_failures(dask_cluster):
    todo = _CountingIterable([f"x{i}" for i in range(12)] + ["raise"])
    runner = run_dask(
        todo, _die_on, ("none",), 1, dask_cluster.scheduler_address, on_error=lambda s, e: (s, e)
    )
    got, in_flight, pids = _drain(runner, todo)
    assert got.pop("raise") == "RuntimeError"
    assert set(got.values()) == {"ok"} and len(got) == 12
    # Two workers in the cluster: at most four submissions in flight.
    assert max(in_flight) <= 2 * WORKERS
    assert len(pids) == WORKERS


# ----------------------------------------------------------------------------- scans


def test_local_and_dask_engines_give_identical_tables(plant, local_scan, tmp_path):
    local, _ = local_scan
    dask = scan(plant, out=tmp_path, engine="dask", workers=WORKERS, gap=False)
    # The analysis is deterministic: the tables are equal value for value.
    pd.testing.assert_frame_equal(
        local.table.sort_index(axis=1), dask.table.sort_index(axis=1), check_exact=True
    )
    assert (local.n_loops, local.n_failed, local.n_skipped) == (N_LOOPS, 0, 0)
    assert (dask.n_loops, dask.n_failed, dask.n_skipped) == (N_LOOPS, 0, 0)


def test_scan_finds_the_sticky_valves(plant, local_scan):
    result, _ = local_scan
    truth = json.loads((plant / "truth.json").read_text())
    table = result.table.set_index("loop")
    assert set(table.index) == set(truth)
    assert set(table["verdict"]) <= set(VERDICT_RANK) - {"error"}
    sticky = {k for k, v in truth.items() if v["sticky"]}
    healthy = set(truth) - sticky
    assert sticky and healthy
    # Loops called stiction are ranked first and none of them has a healthy valve.
    called = set(table.index[table["verdict"] == "stiction"])
    assert called and called <= sticky
    assert not healthy & called


def test_scan_table_is_ranked(local_scan):
    table = local_scan[0].table
    order = table["verdict"].map(VERDICT_RANK).to_numpy()
    assert np.all(np.diff(order) >= 0)
    # Within a verdict, by P(stiction), then severity.
    for _, group in table.groupby("verdict"):
        p = group["probability"].to_numpy()
        assert np.all(np.diff(p) <= 0)
        for _, tied in group.groupby("probability"):
            assert np.all(np.diff(tied["severity"].to_numpy()) <= 0)
    assert list(table["rank"]) == list(range(1, len(table) + 1))


def test_scan_outputs(local_scan):
    result, out = local_scan
    for key, name in (("parquet", "scan.parquet"), ("csv", "scan.csv"), ("html", "index.html")):
        assert Path(result.outputs[key]) == out / name
        assert (out / name).stat().st_size > 0
    back = pd.read_parquet(out / "scan.parquet")
    assert list(back["loop"]) == list(result.table["loop"])
    assert list(pd.read_csv(out / "scan.csv")["loop"]) == list(result.table["loop"])
    html = (out / "index.html").read_text()
    for loop in result.table["loop"]:
        record = json.loads((out / "loops" / f"{loop}.json").read_text())
        assert record["row"]["loop"] == loop and record["analysis"]["loop"] == loop
        assert f'href="loops/{loop}.html"' in html
        page = (out / "loops" / f"{loop}.html").read_text()
        assert f"Loop {loop}" in page and 'href="../index.html"' in page


def _broken_plant(plant: Path, folder: Path) -> Path:
    """Three good loops and three that cannot be read: non-numeric pv, no op, empty."""
    folder.mkdir(parents=True, exist_ok=True)
    for name in ("L0000.csv", "L0001.parquet", "L0002.csv"):
        (folder / name).write_bytes((plant / name).read_bytes())
    good = pd.read_csv(plant / "L0000.csv")
    good.assign(pv="n/a").to_csv(folder / "nonnumeric.csv", index=False)
    good.drop(columns="op").to_csv(folder / "no_op.csv", index=False)
    (folder / "empty.csv").write_text("")
    return folder


def test_broken_loops_are_rows_and_the_others_are_analysed(plant, tmp_path):
    src = _broken_plant(plant, tmp_path / "in")
    result = scan(src, out=tmp_path / "out", workers=WORKERS, gap=False)
    table = result.table.set_index("loop")
    broken = ["empty", "no_op", "nonnumeric"]
    assert result.n_failed == 3 and result.n_loops == 6
    assert sorted(table.index[table["verdict"] == "error"]) == broken
    for loop in broken:
        message = table.loc[loop, "error"]
        assert isinstance(message, str) and message and "\n" not in message
        assert "internal error" not in message  # bad data is diagnosed, not crashed on
    assert "op" in table.loc["no_op", "error"]
    assert set(table.loc[["L0000", "L0001", "L0002"], "verdict"]) <= {
        "stiction",
        "inconclusive",
        "no_stiction",
    }
    # Failed loops come last.
    assert list(result.table["verdict"].iloc[-3:]) == ["error"] * 3


def test_resume_skips_analysed_loops_and_force_reanalyses(plant, tmp_path):
    # workers=1 analyses in this process: four scans without four pool start-ups.
    src = _broken_plant(plant, tmp_path / "in")
    out = tmp_path / "out"
    first = scan(src, out=out, workers=1, gap=False)
    records = {p.name: p.stat().st_mtime_ns for p in (out / "loops").glob("*.json")}
    assert len(records) == 6

    second = scan(src, out=out, workers=1, gap=False)
    # The three good loops are resumed; the three failed ones are tried again.
    assert second.n_skipped == 3
    after = {p.name: p.stat().st_mtime_ns for p in (out / "loops").glob("*.json")}
    for name in ("L0000.json", "L0001.json", "L0002.json"):
        assert after[name] == records[name]
    for name in ("empty.json", "no_op.json", "nonnumeric.json"):
        assert after[name] > records[name]
    pd.testing.assert_frame_equal(first.table, second.table, check_exact=True)

    # Other settings are another analysis: nothing is resumed.
    other = scan(src, out=out, workers=1, gap=False, read_options={"ts": 2.0})
    assert other.n_skipped == 0

    forced = scan(src, out=out, workers=1, gap=False, force=True)
    assert forced.n_skipped == 0
    final = {p.name: p.stat().st_mtime_ns for p in (out / "loops").glob("*.json")}
    assert all(final[k] > after[k] for k in after)
    pd.testing.assert_frame_equal(first.table, forced.table, check_exact=True)


def test_scan_of_a_dataset_matches_the_scan_of_its_files(plant, local_scan, tmp_path):
    frames = []
    for src in discover(plant)[:3]:
        frame = pd.read_csv(src.path) if src.path.endswith(".csv") else pd.read_parquet(src.path)
        frames.append(frame.assign(loop_id=src.loop))
    table = pa.Table.from_pandas(pd.concat(frames), preserve_index=False)
    pq.write_to_dataset(table, tmp_path / "ds", partition_cols=["loop_id"])
    result = scan(tmp_path / "ds", out=tmp_path / "out", workers=1, gap=False)
    files = local_scan[0].table.set_index("loop")
    assert len(result.table) == 3 and result.n_failed == 0
    for _, row in result.table.iterrows():
        ref = files.loc[row["loop"]]
        # The dataset holds the very floats parsed from the files, so the analysis
        # sees the same samples and gives the same numbers, exactly.
        for column in ("verdict", "S", "J", "confidence", "n_samples"):
            assert _same(row[column], ref[column]), column


def _missing(v) -> bool:
    return v is None or (isinstance(v, float) and math.isnan(v))


def _same(a, b) -> bool:
    return (_missing(a) and _missing(b)) or a == b


def test_html_escapes_loop_names(plant, tmp_path):
    evil = "x<b>&\"y'"
    folder = tmp_path / "in"
    folder.mkdir()
    (folder / f"{evil}.csv").write_bytes((plant / "L0000.csv").read_bytes())
    (folder / "empty<i>.csv").write_text("")
    result = scan(folder, out=tmp_path / "out", workers=1, gap=False)
    html = (tmp_path / "out" / "index.html").read_text()
    assert "<b>" not in html and "<i>" not in html
    assert "x&lt;b&gt;&amp;&quot;y&#x27;" in html
    assert set(result.table["loop"]) == {evil, "empty<i>"}
    # Links use the file-system-safe name and the pages exist.
    for name in ("x_b___y_", "empty_i_"):
        assert f'href="loops/{name}.html"' in html
        page = (tmp_path / "out" / "loops" / f"{name}.html").read_text()
        assert "<b>" not in page and "<i>" not in page


def test_scan_rejects_bad_arguments(plant, tmp_path):
    with pytest.raises(UsageError, match="engine"):
        scan(plant, out=tmp_path, engine="spark")
    with pytest.raises(UsageError, match="workers"):
        scan(plant, out=tmp_path, workers=0)


# ------------------------------------------------------------------- names and resume
# (issue 20: outputs read back, duplicate stems, resume by path spelling, nested files)


def _two_loops(folder: Path, plant: Path) -> list[Path]:
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for name in ("L0000.csv", "L0002.csv"):
        paths.append(folder / name)
        paths[-1].write_bytes((plant / name).read_bytes())
    return paths


def test_scan_into_its_own_folder_runs_again(plant, tmp_path):
    folder = tmp_path / "plant"
    _two_loops(folder, plant)
    first = scan(folder, out=folder, workers=1, gap=False)
    assert first.n_loops == 2
    # scan.csv and scan.parquet now lie beside the loops: they are not loops.
    second = scan(folder, out=folder, workers=1, gap=False)
    assert second.n_loops == 2 and second.n_skipped == 2


def test_a_user_file_named_like_the_table_is_not_overwritten(plant, tmp_path):
    folder = tmp_path / "plant"
    _two_loops(folder, plant)
    (folder / "scan.csv").write_bytes((plant / "L0000.csv").read_bytes())
    with pytest.raises(UsageError, match="not written by stiction scan"):
        scan(folder, out=folder, workers=1, gap=False)
    assert (folder / "scan.csv").read_bytes() == (plant / "L0000.csv").read_bytes()


def test_duplicate_stems_and_nested_files_get_distinct_listed_names(plant, tmp_path):
    folder = tmp_path / "plant"
    (folder / "unit2").mkdir(parents=True)
    (folder / "a b.csv").write_bytes((plant / "L0000.csv").read_bytes())
    (folder / "a_b.csv").write_bytes((plant / "L0002.csv").read_bytes())
    (folder / "unit2" / "L0001.parquet").write_bytes((plant / "L0001.parquet").read_bytes())
    (folder / "unit2" / "a b.csv").write_bytes((plant / "L0000.csv").read_bytes())
    sources = discover(folder)
    loops = sorted(s.loop for s in sources)
    # Four files, four names; the nested files are found, not skipped.
    assert len(set(loops)) == 4 and "L0001" in loops and "a b" in loops
    result = scan(folder, out=tmp_path / "out", workers=1, gap=False)
    assert result.n_loops == 4 and len(result.renamed) == 2
    assert len(list((tmp_path / "out" / "loops").glob("*.json"))) == 4


def test_resume_keys_on_resolved_path_and_content(plant, tmp_path, monkeypatch):
    folder = tmp_path / "plant"
    paths = _two_loops(folder, plant)
    out = tmp_path / "out"
    scan(folder, out=out, workers=1, gap=False)
    monkeypatch.chdir(tmp_path)
    # The same files, spelled relative: resumed.
    assert scan(Path("plant"), out=Path("out"), workers=1, gap=False).n_skipped == 2
    # One file edited: that one is analysed again.
    text = paths[0].read_text().splitlines()
    paths[0].write_text("\n".join(text[:-5]) + "\n")
    assert scan(Path("plant"), out=Path("out"), workers=1, gap=False).n_skipped == 1


def test_severity_weighs_size_by_the_probability_of_stiction():
    # P(stiction) x (S + J): 0.5 x 6 = 3 % (exact in binary); the verdict's
    # confidence (0.9 here, 1 - P on a no-stiction call) is used only by rows
    # written before the probability was recorded.
    row = {"S": 4.0, "J": 2.0, "probability": 0.5, "confidence": 0.9}
    assert severity(row) == 3.0
    assert severity({"S": 4.0, "J": 2.0, "probability": float("nan"), "confidence": 0.9}) == (
        pytest.approx(5.4, rel=1e-12)
    )
