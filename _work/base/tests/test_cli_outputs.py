"""Output-side failures are exit 2 and name the path, found before the analysis runs."""

from __future__ import annotations

import errno
import subprocess
import sys
from pathlib import Path

import pytest

from stictiondiag.core.atomic import atomic_path
from stictiondiag.core.errors import UsageError

ROOT = Path(__file__).resolve().parents[1]
HEALTHY = ROOT / "sample_data" / "healthy_flow.csv"
STICTION = Path(sys.executable).with_name("stiction")
UNWRITABLE = Path("/proc/stiction-test")  # no process, root included, may create it

needs_cli = pytest.mark.skipif(
    not STICTION.exists() or not Path("/dev/full").exists() or not Path("/proc").is_dir(),
    reason="needs the console script, /dev/full and /proc",
)


def _run(*args: str, stdout=subprocess.PIPE) -> subprocess.CompletedProcess:
    return subprocess.run(
        [str(STICTION), *args], stdout=stdout, stderr=subprocess.PIPE, text=True, timeout=120
    )


@needs_cli
def test_stdout_on_a_full_device_is_an_output_error():
    # Issue 31: stdout on /dev/full gave exit 3 with a message naming no path.
    with open("/dev/full", "w") as full:
        result = _run("simulate", "--json", "-", "--duration", "200", stdout=full)
    assert result.returncode == 2, result.stderr
    last = result.stderr.strip().splitlines()[-1]
    assert last.startswith("stiction: error: cannot write to standard output")
    assert "Traceback" not in result.stderr and "Exception ignored" not in result.stderr


@needs_cli
@pytest.mark.parametrize("option", ["--json", "--out"])
def test_an_unwritable_output_is_refused_before_the_analysis(option):
    # The analysis of this loop takes seconds; the refusal must come first.
    target = UNWRITABLE / ("a.json" if option == "--json" else "figures")
    result = _run("analyze", str(HEALTHY), "--no-gap", option, str(target))
    assert result.returncode == 2, result.stderr
    assert f"cannot write {target}" in result.stderr
    assert "analysing" not in result.stderr  # it never started


def test_a_full_disk_inside_atomic_path_names_the_destination(tmp_path):
    # A figure written by name (savefig) on a full disk: an output error naming the
    # file, not an OSError that the CLI would take for a data error.
    target = tmp_path / "fig.png"
    with pytest.raises(UsageError, match=f"cannot write {target}: no space left"):
        with atomic_path(target) as tmp:
            tmp.write_bytes(b"half")
            raise OSError(errno.ENOSPC, "No space left on device")
    assert not target.exists() and list(tmp_path.iterdir()) == []


def test_a_failed_print_inside_a_command_is_an_output_error(capsys):
    # typer.echo to a full stdout raises an OSError without a file name: exit 2, not
    # the data error (3) of an unreadable input, which carries its file name.
    import typer

    from stiction_cli.common import friendly_errors

    with pytest.raises(typer.Exit) as stopped:
        with friendly_errors():
            raise OSError(errno.ENOSPC, "No space left on device")
    assert stopped.value.exit_code == 2
    assert "cannot write the output: no space left on device" in capsys.readouterr().err
    with pytest.raises(typer.Exit) as stopped:
        with friendly_errors():
            raise OSError(errno.EACCES, "Permission denied", "/data/loop.csv")
    assert stopped.value.exit_code == 3
