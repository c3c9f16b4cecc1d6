"""Whole-or-nothing output: write_atomic and atomic_path."""

from __future__ import annotations

import os
import stat

import pandas as pd
import pytest
from matplotlib.figure import Figure

from stictiondiag.core.atomic import (
    atomic_path,
    write_atomic,
)
from stictiondiag.core.errors import UsageError


def _leftovers(directory) -> list[str]:
    """Temporary files the atomic writers left behind (hidden ``.*.tmp*`` names)."""
    return [name for name in os.listdir(directory) if ".tmp" in name]


def test_write_text_and_bytes(tmp_path):
    text_path = write_atomic(tmp_path / "a.json", '{"S": 5.0, "unit": "% span"}')
    assert text_path.read_text(encoding="utf-8") == '{"S": 5.0, "unit": "% span"}'
    blob = bytes(range(256))
    write_atomic(tmp_path / "b.bin", blob)
    assert (tmp_path / "b.bin").read_bytes() == blob
    assert _leftovers(tmp_path) == []


def test_creates_parent_directories(tmp_path):
    target = tmp_path / "out" / "nested" / "deeper" / "report.md"
    write_atomic(target, "# report\n")
    assert target.read_text() == "# report\n"


def test_replaces_existing_file_and_keeps_its_permissions(tmp_path):
    target = tmp_path / "summary.csv"
    target.write_text("old")
    os.chmod(target, 0o640)
    write_atomic(target, "new")
    assert target.read_text() == "new"
    assert stat.S_IMODE(target.stat().st_mode) == 0o640


def test_new_file_gets_umask_permissions_not_private_tempfile_mode(tmp_path):
    mask = os.umask(0o022)
    os.umask(mask)
    target = write_atomic(tmp_path / "new.txt", "x")
    assert stat.S_IMODE(target.stat().st_mode) == 0o666 & ~mask


def test_failed_rename_leaves_old_content_and_no_temp_file(tmp_path, monkeypatch):
    target = tmp_path / "result.json"
    target.write_text("previous result")

    def broken_replace(src, dst):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "replace", broken_replace)
    with pytest.raises(UsageError) as info:
        write_atomic(target, "new result")
    assert "\n" not in str(info.value)
    assert str(target) in str(info.value)
    assert target.read_text() == "previous result"
    assert _leftovers(tmp_path) == []


def test_parent_is_a_file_is_a_one_line_usage_error(tmp_path):
    blocker = tmp_path / "not_a_dir"
    blocker.write_text("")
    with pytest.raises(UsageError) as info:
        write_atomic(blocker / "sub" / "x.json", "{}")
    message = str(info.value)
    assert "\n" not in message
    assert "not a directory" in message


def test_directory_as_target_is_a_usage_error(tmp_path):
    with pytest.raises(UsageError, match="directory"):
        write_atomic(tmp_path, "x")


@pytest.mark.skipif(
    not hasattr(os, "geteuid") or os.geteuid() == 0, reason="root can write read-only dirs"
)
def test_read_only_directory_is_a_usage_error(tmp_path):
    locked = tmp_path / "locked"
    locked.mkdir()
    os.chmod(locked, 0o500)
    try:
        with pytest.raises(UsageError, match="cannot write"):
            write_atomic(locked / "x.json", "{}")
    finally:
        os.chmod(locked, 0o700)


def test_non_text_data_is_a_type_error(tmp_path):
    with pytest.raises(TypeError):
        write_atomic(tmp_path / "x", 3.5)  # type: ignore[arg-type]
    assert not (tmp_path / "x").exists()


def test_atomic_path_keeps_extension_for_format_inference(tmp_path):
    figure = Figure(figsize=(2, 2))
    figure.add_subplot().plot([0, 1], [0, 1])
    target = tmp_path / "figs" / "phase.png"
    with atomic_path(target) as temp:
        assert temp.parent == target.parent
        assert temp.suffix == ".png"
        figure.savefig(temp)
        assert not target.exists()  # nothing visible before the block succeeds
    assert target.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert _leftovers(target.parent) == []


def test_atomic_path_parquet_round_trip(tmp_path):
    frame = pd.DataFrame({"pv": [1.0, 2.0, 3.0], "op": [40.0, 50.0, 60.0]})
    target = tmp_path / "table.parquet"
    with atomic_path(target) as temp:
        frame.to_parquet(temp)
    pd.testing.assert_frame_equal(pd.read_parquet(target), frame)


def test_atomic_path_failure_leaves_old_file_and_reraises(tmp_path):
    target = tmp_path / "fig.svg"
    target.write_text("<svg>old</svg>")

    class PlotFailure(RuntimeError):
        pass

    with pytest.raises(PlotFailure):
        with atomic_path(target) as temp:
            temp.write_text("<svg>half")
            raise PlotFailure("renderer crashed")
    assert target.read_text() == "<svg>old</svg>"
    assert _leftovers(tmp_path) == []


def test_atomic_path_unwritable_location(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("")
    with pytest.raises(UsageError, match="not a directory"):
        with atomic_path(blocker / "fig.png"):
            pass
