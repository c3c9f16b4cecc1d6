"""Property: whatever frame a user hands ``stiction analyze``, it ends cleanly.

Hypothesis generates loop files: 0 to 400 rows, columns drawn from real and
misleading names (``pv``, ``FIC1.PV`` beside ``pv``, a duplicate header, ``time``,
``time [ms]``), values that are ordinary, missing, infinite, at the float limits,
text, or timestamps with a typo.  The command runs in-process (Typer's CliRunner)
and must, every time,

* exit with a documented code (0, 1, 2, 3 or 4; :mod:`stictiondiag.core.errors`),
* print no traceback and raise nothing but ``SystemExit``,
* print an error, if any, as one ``stiction: error:`` line,
* leave the input file byte for byte as it was.

Fixed seed (``derandomize``) and a bounded number of examples keep it to seconds.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pandas as pd
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from stiction_cli.main import app

runner = CliRunner()

DOCUMENTED_EXIT_CODES = {0, 1, 2, 3, 4}

_SPECIAL = [np.nan, np.inf, -np.inf, 1.7e308, -1.7e308, 1e-310, 0.0, 1e300]

_NAMES = ["pv", "op", "mv", "sp", "FIC1.PV", "OUT", "valve position", "junk"]
_TIME_NAMES = ["time", "time [ms]", "Timestamp", None]


@st.composite
def loop_frames(draw) -> tuple[str, bytes]:
    """(file suffix, file bytes) of a generated loop record."""
    n = draw(st.one_of(st.integers(0, 60), st.integers(150, 400), st.integers(150, 400)))
    k = np.arange(n, dtype=float)
    period = draw(st.floats(min_value=5, max_value=200))
    scale = draw(st.sampled_from([1.0, 1.0, 1.0, 1.0, 1e-200, 1e200, 1e305]))
    columns: dict[str, object] = {}
    names = ["pv", "op"] if draw(st.integers(0, 3)) else []
    extra = st.sampled_from([n for n in _NAMES if n not in names])
    names += draw(st.lists(extra, min_size=1 - len(names) // 2, max_size=3, unique=True))
    if draw(st.integers(0, 5)) == 0:
        names.append(names[0])  # a repeated header
    for i, name in enumerate(names):
        values = scale * (50 + 10 * np.sin(2 * np.pi * k / period + i))
        kind = draw(st.sampled_from(["clean"] * 6 + ["special", "text", "constant"]))
        if kind == "special" and n:
            where = draw(st.lists(st.integers(0, n - 1), max_size=20))
            values[where] = draw(st.sampled_from(_SPECIAL))
        elif kind == "text" and n:
            text = values.astype(str).astype(object)
            text[:: draw(st.integers(1, 5))] = draw(st.sampled_from(["Bad", "", "1,5", "n/a"]))
            values = text
        elif kind == "constant":
            values = np.full(n, 3.0)
        key = name if name not in columns else f"{name} "  # duplicate header after strip
        columns[key] = values
    time_name = draw(st.sampled_from(_TIME_NAMES))
    if time_name is not None:
        step = draw(st.sampled_from([1.0, 0.5, 1000.0, 1 / 86400]))
        start = draw(st.sampled_from([0.0, 1.7e9, 1.7e12, 45000.0]))
        t = start + step * k
        if n and draw(st.integers(0, 3)) == 0:
            t[draw(st.integers(0, n - 1))] = draw(st.sampled_from([1e15, -1e9, np.nan, 4e9]))
        columns[time_name] = t
    frame = pd.DataFrame(columns)
    if draw(st.booleans()):
        return ".csv", frame.to_csv(index=False).encode()
    if draw(st.booleans()):
        text = frame.to_csv(index=False, sep=";")
        return ".csv", text.encode("latin-1", errors="replace")
    seen: set[str] = set()
    unique = []
    for c in frame.columns:  # Parquet needs distinct names
        c = str(c).strip()
        while c in seen:
            c += "_"
        seen.add(c)
        unique.append(c)
    frame.columns = unique
    from io import BytesIO

    buffer = BytesIO()
    frame.to_parquet(buffer)
    return ".parquet", buffer.getvalue()


@settings(
    max_examples=60,
    deadline=None,
    derandomize=True,
    database=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)
@given(case=loop_frames())
def test_analyze_ends_cleanly_on_any_frame(case, tmp_path_factory):
    suffix, data = case
    folder = tmp_path_factory.mktemp("prop")
    path = folder / f"loop{suffix}"
    path.write_bytes(data)
    digest = hashlib.sha256(data).hexdigest()
    out = folder / "out.json"
    result = runner.invoke(app, ["analyze", str(path), "--no-gap", "--json", str(out)])
    event(f"exit {result.exit_code}")
    assert result.exit_code in DOCUMENTED_EXIT_CODES, result.output
    assert result.exception is None or isinstance(result.exception, SystemExit), repr(
        result.exception
    )
    assert "Traceback" not in result.output
    errors = [line for line in result.stderr.splitlines() if line.startswith("stiction: error")]
    if result.exit_code in (2, 3):
        assert len(errors) == 1, result.stderr
    assert hashlib.sha256(Path(path).read_bytes()).hexdigest() == digest
