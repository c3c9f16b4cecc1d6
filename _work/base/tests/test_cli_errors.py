"""One error format: every option of every command, given a bad value.

The test walks the Click command tree behind the Typer app, so an option added later
is walked too: each option gets bad values derived from its type (a word for a
number, a value below its minimum, an unknown choice, a value for a flag), plus
the semantic bad values listed in :data:`SEMANTIC` (a zero sample time, a scheduler
that is no address, an output path that is the input, ...).  Each run must end with
exit code 2 and exactly one line on stderr, ``stiction: error: ...``, and no
traceback.  Bad values are rejected before any data is read, so the walk is fast.
"""

from __future__ import annotations

import enum
import hashlib
import types
import typing
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import typer
from typer.testing import CliRunner

from stiction_cli.main import app

runner = CliRunner()

#: Bad values that parse but make no sense, per (command, option); "{input}" is the
#: input file, "{dir}" an existing folder, "{file}" an existing non-input file.
SEMANTIC: dict[tuple[str, str], list[list[str]]] = {
    ("*", "--ts"): [["0"], ["-1"], ["nan"], ["inf"]],
    ("*", "--op-range"): [["5", "1"], ["nan", "1"]],
    ("*", "--json"): [["{dir}"], ["{file}/x.json"]],
    ("analyze", "--json"): [["{input}"]],
    ("gap", "--json"): [["{input}"]],
    ("analyze", "--out"): [["{file}"]],
    ("report", "--out"): [["{file}"]],
    ("report", "--markdown"): [["{input}"], ["{dir}"]],
    ("report", "--fail-on-stiction"): [["2"], ["-0.5"]],
    ("report", "--workers"): [["0"]],
    ("scan", "--out"): [["{file}"], ["{file}/sub"]],
    ("scan", "--workers"): [["0"]],
    ("scan", "--scheduler"): [["garbage://"]],
    ("scan", "--ts"): [["0"], ["-1"]],
    ("scan", "--loops"): [["{dir}"], ["{file}/x.csv"]],
    ("report", "--loops"): [["{dir}"], ["{file}/x.csv"], ["{input}"]],
    ("gap", "--plot"): [["{dir}"], ["{input}"], ["x.xyz"]],
    ("simulate", "--seed"): [["-1"]],
    ("simulate", "--plot"): [["x.xyz"], ["{dir}"]],
    ("simulate", "--csv"): [["{dir}"]],
    ("simulate", "--S"): [["abc"], ["-1"]],
    ("simulate", "--duration"): [["0"], ["nan"]],
    ("benchmark", "--cases"): [["0"]],
    ("benchmark", "--out"): [["{file}"]],
    ("validate", "--workers"): [["0"]],
    ("validate", "--loops"): [["CHEM1,not a name"], [","]],
    ("validate", "--out"): [["{dir}"]],
}

#: Options whose value is free text checked against the data (a column name):
#: a wrong one is a data error (exit 3), reached only by reading the file.
FREE_TEXT = {
    "--pv",
    "--op",
    "--mv",
    "--sp",
    "--time",
    "--mode",
    "--loop-column",
    "--isdb",
    "--loop",
    "--valve",
    "--case",
    "--Fs",
    "--Fc",
    "--Fv",
    "--calibration",
    "--dt",
    "--integral-band",
    "--noise",
    "--kick",
    "--J",
}


def _commands() -> dict:
    group = typer.main.get_command(app)
    return dict(group.commands)  # type: ignore[attr-defined]


def _base_type(annotation):
    """The value type behind ``Annotated[X | None, ...]``."""
    while typing.get_origin(annotation) is typing.Annotated:
        annotation = typing.get_args(annotation)[0]
    args = [a for a in typing.get_args(annotation) if a is not type(None)]
    if typing.get_origin(annotation) in (types.UnionType, typing.Union) and len(args) == 1:
        annotation = args[0]
    return annotation


def _typed_bad_values(command, param) -> list[list[str]]:
    """Bad values a parser must refuse, from the option's declared type alone."""
    if getattr(param, "is_flag", False):
        return [[f"{param.opts[0]}=yes"]]  # a flag takes no value
    hints = typing.get_type_hints(command.callback, include_extras=True)
    kind = _base_type(hints[param.name])
    if isinstance(kind, type) and issubclass(kind, enum.Enum):
        return [["garbage"]]
    if kind in (int, float):
        values = [["abc"]]
        if getattr(param, "min", None) is not None:
            values.append([str(param.min - 1)])
        return values
    if typing.get_origin(kind) is tuple:
        return [["abc"] * param.nargs, ["1"]]  # a word, and too few values
    return []


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> dict[str, str]:
    root = tmp_path_factory.mktemp("walk")
    k = np.arange(300)
    frame = pd.DataFrame({"time": k, "pv": np.sin(k / 9.0), "op": 50 + 10 * np.cos(k / 9.0)})
    data = root / "loop.csv"
    frame.to_csv(data, index=False)
    other = root / "other.txt"
    other.write_text("not a folder\n")
    (root / "folder").mkdir()
    return {"input": str(data), "dir": str(root / "folder"), "file": str(other), "root": str(root)}


def _cases(files: dict[str, str]) -> list[tuple[str, list[str]]]:
    cases = []
    for name, command in sorted(_commands().items()):
        for param in command.params:
            if not hasattr(param, "opts") or not param.opts[0].startswith("--"):
                continue
            option = param.opts[0]
            bad = _typed_bad_values(command, param)
            for key in ((name, option), ("*", option)):
                bad += SEMANTIC.get(key, [])
            assert bad or option in FREE_TEXT, f"no bad value for {name} {option}"
            for values in bad:
                values = [v.format(**files) for v in values]
                args = values if values[0].startswith("--") else [option, *values]
                cases.append((name, args))
    return cases


def _argv(command: str, args: list[str], files: dict[str, str]) -> list[str]:
    data = files["input"]
    if command in ("analyze", "gap", "report"):
        return [command, data, *args]
    if command == "scan":
        return [command, str(Path(data).parent), *args]
    if command == "simulate":
        return [command, "--duration", "50", *args]
    # Were a bad value let through, these fail at once instead of running for minutes
    # (an empty ISDB folder; a single benchmark case).  The walked option comes last,
    # so it wins over these.
    if command == "validate":
        return [command, "--isdb", files["dir"], *args]
    if command == "benchmark":
        return [command, "--cases", "1", "--out", str(Path(files["dir"]) / "b"), *args]
    return [command, *args]


def test_every_option_of_every_command_fails_on_one_line_with_exit_2(files, monkeypatch):
    monkeypatch.chdir(files["root"])
    cases = _cases(files)
    # Every command is walked, each through more than one option.
    assert {name for name, _ in cases} >= {
        "analyze",
        "gap",
        "report",
        "scan",
        "simulate",
        "benchmark",
        "validate",
    }
    before = hashlib.sha256(Path(files["input"]).read_bytes()).hexdigest()
    failures = []
    for command, args in cases:
        argv = _argv(command, args, files)
        result = runner.invoke(app, argv)
        lines = [line for line in result.stderr.splitlines() if line.strip()]
        ok = (
            result.exit_code == 2
            and len(lines) == 1
            and lines[0].startswith("stiction: error: ")
            and "Traceback" not in result.output
        )
        if not ok:
            failures.append(f"{' '.join(argv)} -> exit {result.exit_code}: {lines[-3:]}")
    assert not failures, "\n".join(failures)
    assert hashlib.sha256(Path(files["input"]).read_bytes()).hexdigest() == before


@pytest.mark.parametrize(
    "argv",
    [
        ["analyze"],  # missing argument
        ["analyze", "x.csv", "--no-such-option"],
        ["no-such-command"],
        ["report", "--out", "r"],  # no input files
    ],
)
def test_click_usage_errors_are_one_line(argv, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    result = runner.invoke(app, argv)
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert result.exit_code == 2
    assert len(lines) == 1 and lines[0].startswith("stiction: error: "), lines


def test_unreadable_input_is_a_data_error_on_one_line(tmp_path):
    missing = tmp_path / "nope.csv"
    result = runner.invoke(app, ["analyze", str(missing), "--no-gap"])
    lines = [line for line in result.stderr.splitlines() if line.startswith("stiction:")]
    assert result.exit_code == 3
    assert len(lines) == 1 and "nope.csv" in lines[0]
