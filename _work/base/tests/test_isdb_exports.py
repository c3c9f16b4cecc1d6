"""Whole-plant exports built at test time from 16 ISDB loops (scripts/make_isdb_plant.py).

Plain, compressed ("recorded values") and Yokogawa-named, wide and long: every loop is
found and read whole on its own sample time.  The ISDB is read from ../shared or
$STICTION_ISDB and never copied into the repository; the tests skip without it.
"""

from __future__ import annotations

import importlib.util
import os
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from stictiondiag.io.plant import plant_loops, read_plant_loop

ROOT = Path(__file__).resolve().parents[1]
ISDB = Path(os.environ.get("STICTION_ISDB", ROOT.parent / "shared" / "data" / "isdb"))

pytestmark = [
    pytest.mark.isdb,
    pytest.mark.skipif(not (ISDB / "manifest.csv").is_file(), reason="ISDB not present"),
]


@pytest.fixture(scope="module")
def exports(tmp_path_factory):
    spec = importlib.util.spec_from_file_location(
        "make_isdb_plant", ROOT / "scripts" / "make_isdb_plant.py"
    )
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    out = tmp_path_factory.mktemp("isdb_plant")
    return module.build(ISDB, out), pd.read_csv(out / "tags.csv").set_index("tag"), module


@pytest.mark.parametrize(
    "form",
    [
        "plant_wide",
        "plant_long",
        "plant_long_compressed",
        "plant_wide_compressed",
        "plant_yokogawa",
    ],
)
def test_every_loop_of_every_form_is_read_whole(exports, form):
    paths, tags, module = exports
    loops = plant_loops(paths[form])
    assert sorted(loop.loop for loop in loops) == sorted(tags.index)
    isdb = module.loops(ISDB)
    by_tag = {lp["tag"]: lp for lp in isdb}
    for loop in loops:
        record = read_plant_loop(loop)
        truth = by_tag[loop.loop]
        # Each loop on its own sample time, every sample of its record.
        assert record.ts == pytest.approx(truth["ts"], rel=1e-9)
        assert record.n == truth["pv"].size
        assert record.start_time == START_S
        if "compressed" in form:
            # Rebuilt from the archive within twice the swinging door's deviation of
            # every sample (io.compression; 0.2 % of the tag's range), the sp within the
            # deadband: the reconstruction the historian itself would show.
            for role in ("pv", "op"):
                bound = 2 * module.DEVIATION * np.ptp(truth[role]) + 1e-9
                assert np.max(np.abs(getattr(record, role) - truth[role])) <= bound
            assert any("compressed archive" in w for w in record.warnings)
        else:
            np.testing.assert_allclose(record.pv, truth["pv"], rtol=1e-12, atol=1e-9)
            np.testing.assert_allclose(record.op, truth["op"], rtol=1e-12, atol=1e-9)
        if form == "plant_yokogawa":
            assert record.names["op"].endswith(".MV")
            assert any("read as the controller output" in w for w in record.warnings)


START_S = pd.Timestamp("2024-03-01", tz="UTC").timestamp()
