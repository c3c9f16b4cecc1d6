"""Hostile-user fuzz of the ``stiction`` command: malformed inputs, interrupts, reruns.

Builds malformed loop files (empty, binary, wrong delimiters and encodings, text in
numbers, non-finite and extreme values, duplicate and ambiguous columns, broken
clocks and time units, corrupt Parquet and archives, a 20 000-field row, ...) and
runs ``stiction analyze --no-gap`` on each in a fresh process, then interrupts
``scan`` (local pool and Dask), ``report``, ``analyze`` and ``simulate`` with SIGINT
sent to the whole process group (as Ctrl-C in a terminal does) at several moments,
and reruns each.

For every case it records the exit code, whether a traceback was printed, whether
an error took more than one line, whether any input file changed (SHA-256 before and
after), whether a half-written file was left (temporary files, unparsable JSON) and,
for reruns, whether they completed.  It prints one table and a summary line.

Run:  python scripts/fuzz_cli.py [--dir /tmp/stiction_fuzz] [--quick]

Each process runs with a 3 GB address-space limit, so a runaway allocation fails
instead of taking the machine.  --quick runs a third of the interrupt scenarios.
"""

from __future__ import annotations

import argparse
import bz2
import gzip
import hashlib
import json
import os
import resource
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

ALLOWED_EXIT = {0, 1, 2, 3, 4}
MEMORY_LIMIT = 3 * 1024**3
ROOT = Path(__file__).resolve().parents[1]


def stiction_argv() -> list[str]:
    """The command, run from this checkout (its ``cli`` package as ``stiction_cli``)."""
    code = (
        "import sys, importlib, types;"
        f"sys.path.insert(0, {str(ROOT)!r});"
        "import cli; sys.modules['stiction_cli'] = cli;"
        "from cli.main import main; sys.argv[0] = 'stiction'; main()"
    )
    return [sys.executable, "-c", code]


def _limit() -> None:
    resource.setrlimit(resource.RLIMIT_AS, (MEMORY_LIMIT, MEMORY_LIMIT))


def sha(path: Path) -> str:
    if path.is_dir():
        return "dir"
    try:
        return hashlib.sha256(path.read_bytes()).hexdigest()
    except OSError:
        return "unreadable"


# --------------------------------------------------------------------------- inputs


def _loop(n: int = 1500, seed: int = 0) -> pd.DataFrame:
    """A cycling loop (a square-ish op through a sticky response) at 1 s."""
    rng = np.random.default_rng(seed)
    k = np.arange(n)
    op = 50 + 8 * np.sin(2 * np.pi * k / 90)
    mv = np.round(op / 2.0) * 2.0
    pv = 20 + 0.5 * np.convolve(mv - 50, np.ones(8) / 8, mode="same") + rng.normal(0, 0.05, n)
    return pd.DataFrame({"time": k.astype(float), "sp": 20.0, "pv": pv, "op": op, "mv": mv})


class _Inputs:
    """The malformed inputs written so far into ``folder``, as (case name, path) in
    order, and the well-formed loop (``base``, its CSV ``text``, its ISO stamps) they
    are made from."""

    def __init__(self, folder: Path, base: pd.DataFrame) -> None:
        self.folder = folder
        self.base = base
        self.text = base.to_csv(index=False)
        self.iso = pd.Timestamp("2024-01-01") + pd.to_timedelta(base.time, unit="s")
        self.cases: list[tuple[str, Path]] = []

    def frame(self, name: str, df: pd.DataFrame, **kw) -> None:
        path = self.folder / f"{name}.csv"
        df.to_csv(path, index=False, **kw)
        self.cases.append((name, path))

    def raw(self, name: str, data: bytes, suffix: str = ".csv") -> None:
        path = self.folder / f"{name}{suffix}"
        path.write_bytes(data)
        self.cases.append((name, path))

    def mod(self, name: str, fn) -> None:
        df = self.base.copy()
        df = fn(df) if fn(df) is not None else df
        self.frame(name, df)


def _content_cases(w: _Inputs) -> None:
    """Empty, binary and truncated files, missing columns, text in numbers."""
    w.raw("empty", b"")
    w.raw("header_only", b"time,pv,op\n")
    w.raw("binary", bytes(range(256)) * 40)
    w.raw("nul_bytes", w.text.encode().replace(b"\n", b"\x00\n", 50))
    w.raw("one_column", ("pv\n" + "\n".join(map(str, w.base.pv))).encode())
    w.frame("no_pv", w.base.drop(columns=["pv"]))
    w.frame("no_op", w.base.drop(columns=["op", "mv"]))
    w.mod("text_pv", lambda d: d.assign(pv="abc"))
    w.mod("mostly_text_op", lambda d: d.assign(op=np.where(d.index % 3, "Bad", d.op.astype(str))))
    w.mod(
        "some_bad_pv", lambda d: d.assign(pv=np.where(d.index % 50 == 0, "Bad", d.pv.astype(str)))
    )
    w.mod("all_nan_pv", lambda d: d.assign(pv=np.nan))
    w.mod("constant_pv", lambda d: d.assign(pv=1.0))
    w.frame("five_rows", w.base.head(5))
    w.frame("ninety_nine_rows", w.base.head(99))


def _extreme_value_cases(w: _Inputs) -> None:
    """Non-finite, huge, tiny and subnormal values."""
    w.mod("inf_pv", lambda d: d.assign(pv=np.where(d.index % 97 == 0, np.inf, d.pv)))
    w.mod("neg_inf_op", lambda d: d.assign(op=np.where(d.index % 89 == 0, -np.inf, d.op)))
    w.mod("all_inf_pv", lambda d: d.assign(pv=np.inf))
    w.mod("inf_time", lambda d: d.assign(time=np.where(d.index == 700, np.inf, d.time)))
    w.mod("huge_pv", lambda d: d.assign(pv=d.pv * 1e305))
    w.mod("huge_all", lambda d: d.assign(pv=d.pv * 1e300, op=d.op * 1e300, mv=d.mv * 1e300))
    w.mod("tiny_pv", lambda d: d.assign(pv=d.pv * 1e-305))
    w.mod("tiny_all", lambda d: d.assign(pv=d.pv * 1e-300, op=d.op * 1e-300, mv=d.mv * 1e-300))
    w.mod("max_float", lambda d: d.assign(pv=np.where(d.index % 2, 1.7e308, -1.7e308)))
    w.mod("subnormal", lambda d: d.assign(op=d.op * 1e-320))
    w.mod("huge_sp", lambda d: d.assign(sp=1e308))


def _column_cases(w: _Inputs) -> None:
    """Duplicate and ambiguous columns."""
    w.raw("dup_pv", w.text.replace("time,sp,pv,op,mv", "time,pv,pv,op,mv", 1).encode())
    w.mod("two_pv_like", lambda d: d.rename(columns={"pv": "FIC1.PV"}).assign(**{"FIC2.PV": d.pv}))


def _clock_cases(w: _Inputs) -> None:
    """Broken clocks and time units: epochs, serial dates, ISO stamps with typos."""
    w.mod("epoch_ms", lambda d: d.assign(time=1.7e12 + d.time * 1000))
    w.mod("epoch_us", lambda d: d.assign(time=1.7e15 + d.time * 1e6))
    w.mod("epoch_ns", lambda d: d.assign(time=(1.7e18 + d.time * 1e9).astype("int64")))
    w.mod("excel_serial", lambda d: d.assign(time=45000 + d.time / 86400))
    w.mod("ambiguous_serial", lambda d: d.assign(time=45000 + d.time * 0.05))
    w.mod(
        "time_ms_header",
        lambda d: d.rename(columns={"time": "time [ms]"}).assign(**{"time [ms]": d.time * 1000}),
    )
    w.mod("iso", lambda d: d.assign(time=w.iso.dt.strftime("%Y-%m-%dT%H:%M:%S")))
    typo = w.iso.dt.strftime("%Y-%m-%dT%H:%M:%S").copy()
    typo.iloc[700] = "2204-01-01T00:11:40"
    w.mod("iso_typo_future", lambda d: d.assign(time=typo))
    typo2 = w.iso.dt.strftime("%Y-%m-%dT%H:%M:%S").copy()
    typo2.iloc[3] = "1024-01-01T00:00:03"
    w.mod("iso_typo_past", lambda d: d.assign(time=typo2))
    w.mod("one_far_stamp", lambda d: d.assign(time=np.where(d.index == 800, 1e12, d.time)))
    w.mod("one_far_stamp_e15", lambda d: d.assign(time=np.where(d.index == 5, 1e15, d.time)))
    w.mod("decreasing_time", lambda d: d.assign(time=d.time[::-1].to_numpy()))
    w.mod("repeated_time", lambda d: d.assign(time=d.time // 3))
    w.mod("same_time", lambda d: d.assign(time=5.0))
    w.mod("nan_time", lambda d: d.assign(time=np.nan))
    w.mod("text_time", lambda d: d.assign(time="yesterday"))
    w.mod("negative_time", lambda d: d.assign(time=d.time - 1e6))
    w.mod(
        "tz_mixed",
        lambda d: d.assign(
            time=np.where(
                d.index % 2,
                w.iso.dt.strftime("%Y-%m-%dT%H:%M:%S+01:00"),
                w.iso.dt.strftime("%Y-%m-%dT%H:%M:%SZ"),
            )
        ),
    )


def _layout_cases(w: _Inputs) -> None:
    """Delimiters, encodings, line endings, very wide rows and odd names."""
    w.frame("semicolon", w.base, sep=";")
    w.frame("tab", w.base, sep="\t")
    w.raw("latin1", w.text.replace("pv", "pv [\u00b0C]", 1).encode("latin-1"))
    w.raw("bom", b"\xef\xbb\xbf" + w.text.encode())
    w.raw("trailing_commas", w.text.replace("\n", ",\n").encode())
    w.raw("wide_row", (w.text + ",".join(["1"] * 20000) + "\n").encode())
    w.raw("wide_header", (",".join(f"c{i}" for i in range(20000)) + "\n1,2\n").encode())
    w.raw("long_line", ("time,pv,op\n" + "9" * 2_000_000 + ",1,2\n").encode())
    w.raw("crlf", w.text.replace("\n", "\r\n").encode())
    w.raw("cr_only", w.text.replace("\n", "\r").encode())
    w.raw("comma_decimal", w.base.to_csv(index=False, sep=";", decimal=",").encode())
    w.raw("quoted_newlines", w.text.replace("pv", '"p\nv"', 1).encode())
    w.raw("script_names", w.text.replace("pv", "<script>alert(1)</script>.pv", 1).encode())
    w.raw("unicode_names", w.text.replace("pv", "\u6e29\u5ea6.PV", 1).encode())


def _container_cases(w: _Inputs) -> None:
    """Compressed files, Parquet, other formats, a directory, a missing path."""
    w.raw("gz_valid", gzip.compress(w.text.encode()), ".csv.gz")
    w.raw("gz_corrupt", gzip.compress(w.text.encode())[:500], ".csv.gz")
    w.raw("bz2_garbage", b"BZh91AY&SYgarbage", ".csv.bz2")
    w.raw("xz_garbage", b"\xfd7zXZ\x00garbage", ".csv.xz")
    w.raw("bz2_valid", bz2.compress(w.text.encode()), ".csv.bz2")
    w.raw("parquet_garbage", b"PAR1" + os.urandom(2000) + b"PAR1", ".parquet")
    w.raw("parquet_empty_bytes", b"", ".parquet")
    empty_pq = w.folder / "parquet_no_rows.parquet"
    w.base.head(0).to_parquet(empty_pq)
    w.cases.append(("parquet_no_rows", empty_pq))
    dt_pq = w.folder / "parquet_datetime_index.parquet"
    w.base.drop(columns="time").set_index(pd.DatetimeIndex(w.iso, name="ts")).to_parquet(dt_pq)
    w.cases.append(("parquet_datetime_index", dt_pq))
    bool_pq = w.folder / "parquet_bool_pv.parquet"
    w.base.assign(pv=w.base.index % 2 == 0).to_parquet(bool_pq)
    w.cases.append(("parquet_bool_pv", bool_pq))
    w.raw("spreadsheet", b"PK\x03\x04 not really", ".xlsx")
    w.raw("unknown_ext", w.text.encode(), ".dat")
    w.raw("no_ext", w.text.encode(), "")
    dir_csv = w.folder / "directory.csv"
    dir_csv.mkdir(exist_ok=True)
    w.cases.append(("directory", dir_csv))
    w.cases.append(("missing", w.folder / "does_not_exist.csv"))


def _gap_cases(w: _Inputs) -> None:
    """Gaps, odd ranges and odd signals in otherwise readable files."""
    w.mod("nan_blocks", lambda d: d.assign(pv=np.where((d.index // 40) % 3 == 0, np.nan, d.pv)))
    w.mod(
        "nan_edges",
        lambda d: d.assign(pv=np.where((d.index < 30) | (d.index > 1450), np.nan, d.pv)),
    )
    w.mod("alternate_nan", lambda d: d.assign(op=np.where(d.index % 2, np.nan, d.op)))
    w.mod("mA_out_of_range", lambda d: d.assign(op=d.op * 1000))
    w.mod("random_pv", lambda d: d.assign(pv=np.random.default_rng(1).normal(0, 1, len(d))))
    w.mod("op_one_step", lambda d: d.assign(op=np.where(d.index > 700, 60.0, 40.0)))


def build_inputs(folder: Path) -> list[tuple[str, Path]]:
    """Write the malformed inputs; returns (case name, path)."""
    folder.mkdir(parents=True, exist_ok=True)
    w = _Inputs(folder, _loop())
    for write in (
        _content_cases,
        _extreme_value_cases,
        _column_cases,
        _clock_cases,
        _layout_cases,
        _container_cases,
        _gap_cases,
    ):
        write(w)
    return w.cases


# --------------------------------------------------------------------------- running


@dataclass
class Outcome:
    group: str
    case: str
    code: int | None
    seconds: float
    traceback: bool
    multi_line_error: bool
    inputs_changed: int
    partial_files: int
    note: str = ""


def _error_lines(stderr: str) -> list[str]:
    return [line for line in stderr.splitlines() if "error" in line.lower()]


def run(argv: list[str], cwd: Path, timeout: float = 240) -> tuple[int | None, str, float]:
    t0 = time.perf_counter()
    try:
        proc = subprocess.run(
            stiction_argv() + argv,
            cwd=cwd,
            capture_output=True,
            text=True,
            timeout=timeout,
            preexec_fn=_limit,
            env={**os.environ, "STICTION_DEBUG": ""},
        )
        return proc.returncode, proc.stderr + proc.stdout, time.perf_counter() - t0
    except subprocess.TimeoutExpired as exc:
        out = (exc.stderr or b"").decode(errors="replace") if isinstance(exc.stderr, bytes) else ""
        return None, out + "\n<timeout>", time.perf_counter() - t0


def partial_files(folder: Path) -> int:
    """Temporary files left behind, and JSON files that do not parse."""
    bad = 0
    for f in folder.rglob("*"):
        if f.is_file() and ".tmp" in f.name:
            bad += 1
        elif f.is_file() and f.suffix == ".json":
            try:
                json.loads(f.read_text())
            except (OSError, ValueError):
                bad += 1
    return bad


def fuzz_inputs(work: Path) -> list[Outcome]:
    folder = work / "inputs"
    cases = build_inputs(folder)
    outcomes = []
    for name, path in cases:
        before = sha(path)
        out_json = work / "out" / f"{name}.json"
        code, text, seconds = run(["analyze", str(path), "--no-gap", "--json", str(out_json)], work)
        errors = _error_lines(text)
        outcomes.append(
            Outcome(
                "input",
                name,
                code,
                seconds,
                "Traceback" in text,
                code in (2, 3)
                and (len(errors) != 1 or not errors[0].startswith("stiction: error:")),
                int(sha(path) != before),
                partial_files(work / "out") if (work / "out").exists() else 0,
                (errors[-1][:90] if errors else "").replace("|", "/"),
            )
        )
        print(f"  input {name}: exit {code} ({seconds:.1f} s)", file=sys.stderr, flush=True)
    return outcomes


def interrupt(argv: list[str], cwd: Path, after: float, grace: float = 30.0):
    """Start the command in its own process group, SIGINT the group after ``after`` s."""
    proc = subprocess.Popen(
        stiction_argv() + argv,
        cwd=cwd,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
        preexec_fn=_limit,
    )
    time.sleep(after)
    t0 = time.perf_counter()
    try:
        os.killpg(proc.pid, signal.SIGINT)
    except ProcessLookupError:
        pass
    try:
        out, err = proc.communicate(timeout=grace)
        hung = False
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        out, err = proc.communicate()
        hung = True
    return proc.returncode, err + out, time.perf_counter() - t0, hung


def _plant(folder: Path, n: int) -> list[Path]:
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for i in range(n):
        path = folder / f"loop{i:02d}.csv"
        _loop(1200, seed=i).to_csv(path, index=False)
        paths.append(path)
    return paths


def fuzz_interrupts(work: Path, quick: bool) -> list[Outcome]:
    outcomes = []
    delays = [0.3, 1.5, 4.0, 8.0] if not quick else [1.5, 6.0]
    scenarios = []
    for d in delays:
        scenarios.append(("scan_local", d, ["--workers", "2"]))
    for d in delays[:3] if not quick else delays[:1]:
        scenarios.append(("scan_dask", d, ["--engine", "dask", "--workers", "2"]))
    for d in delays:
        scenarios.append(("report", d, []))
    for d in delays[:3]:
        scenarios.append(("report_workers", d, ["--workers", "2"]))
    for d in delays[:3]:
        scenarios.append(("analyze", d, []))
    for d in delays[:3]:
        scenarios.append(("simulate", d, []))
    for d in delays[:2]:
        scenarios.append(("scan_local_gap", d, ["--workers", "2", "--gap"]))
    for k, (kind, delay, extra) in enumerate(scenarios):
        case_dir = work / f"int{k:02d}_{kind}"
        shutil.rmtree(case_dir, ignore_errors=True)
        inputs = _plant(case_dir / "plant", 4)
        hashes = {p: sha(p) for p in inputs}
        if kind.startswith("scan"):
            gap = "--gap" if "--gap" in extra else "--no-gap"
            argv = ["scan", "plant", "--out", "out", gap, *[e for e in extra if e != "--gap"]]
            rerun = argv
        elif kind.startswith("report"):
            argv = [
                "report",
                *[f"plant/{p.name}" for p in inputs],
                "--out",
                "out",
                "--no-gap",
                *extra,
            ]
            rerun = [*argv, "--clean"]
        elif kind == "analyze":
            argv = ["analyze", f"plant/{inputs[0].name}", "--json", "out/a.json", "--out", "out"]
            rerun = argv
        else:
            argv = [
                "simulate",
                "--duration",
                "20000",
                "--csv",
                "out/sim.csv",
                "--json",
                "out/sim.json",
            ]
            rerun = ["simulate", "--duration", "500", "--csv", "out/sim.csv"]
        code, text, seconds, hung = interrupt(argv, case_dir, delay)
        partial = partial_files(case_dir / "out") if (case_dir / "out").exists() else 0
        lines = [line for line in text.splitlines() if line.strip()]
        interrupted_lines = [line for line in lines if "interrupted" in line]
        note = "hung" if hung else ""
        if code == 130 and len(interrupted_lines) != 1:
            note += f" {len(interrupted_lines)} interrupt lines"
        rcode, rtext, rseconds = run(rerun, case_dir)
        if "Traceback" in text or "Traceback" in rtext:
            (case_dir / "stderr.txt").write_text(text + "\n---- rerun ----\n" + rtext)
            note += f" (output in {case_dir / 'stderr.txt'})"
        partial += partial_files(case_dir / "out") if (case_dir / "out").exists() else 0
        changed = sum(sha(p) != h for p, h in hashes.items())
        outcomes.append(
            Outcome(
                "interrupt",
                f"{kind} @{delay:g}s",
                code,
                seconds,
                "Traceback" in text or "Traceback" in rtext,
                code not in (0, 130) and len(_error_lines(text)) > 1,
                changed,
                partial,
                (note + f" rerun exit {rcode} ({rseconds:.0f} s)").strip(),
            )
        )
        print(f"  {kind} @{delay}: exit {code}, rerun {rcode}", file=sys.stderr, flush=True)
    return outcomes


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dir", type=Path, default=Path("/tmp/stiction_fuzz"))
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--skip-interrupts", action="store_true")
    parser.add_argument("--skip-inputs", action="store_true")
    args = parser.parse_args()
    work = args.dir.resolve()
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir(parents=True)
    t0 = time.perf_counter()
    outcomes = [] if args.skip_inputs else fuzz_inputs(work)
    if not args.skip_interrupts:
        outcomes += fuzz_interrupts(work, args.quick)
    print(
        "| group | case | exit | s | traceback | multi-line error | inputs changed | "
        "partial files | note |"
    )
    print("|---|---|---:|---:|---|---|---:|---:|---|")
    for o in outcomes:
        print(
            f"| {o.group} | {o.case} | {o.code} | {o.seconds:.1f} | {'YES' if o.traceback else ''} "
            f"| {'YES' if o.multi_line_error else ''} | {o.inputs_changed} | {o.partial_files} "
            f"| {o.note} |"
        )
    n_in = sum(o.group == "input" for o in outcomes)
    n_int = sum(o.group == "interrupt" for o in outcomes)
    bad_exit = sum(
        o.code not in ALLOWED_EXIT and not (o.group == "interrupt" and o.code == 130)
        for o in outcomes
    )
    print(
        f"\n{n_in} malformed inputs, {n_int} interrupt/rerun scenarios in "
        f"{time.perf_counter() - t0:.0f} s: "
        f"{sum(o.traceback for o in outcomes)} tracebacks, "
        f"{sum(o.inputs_changed for o in outcomes)} inputs changed, "
        f"{sum(o.multi_line_error for o in outcomes)} multi-line errors, "
        f"{sum(o.partial_files for o in outcomes)} partial files, "
        f"{bad_exit} undocumented exit codes (timeouts included), "
        f"{sum('hung' in o.note for o in outcomes)} hangs"
    )


if __name__ == "__main__":
    main()
