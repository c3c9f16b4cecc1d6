"""One JSON round trip for every result (stictiondiag.core.schema): an analysis
written with ``Analysis.to_json`` reads back as the same typed object."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pytest

from stictiondiag.analysis import Analysis, AnalysisConfig, analyze_file
from stictiondiag.core.errors import DataError
from stictiondiag.core.schema import SCHEMA_VERSION, decode, dumps, encode, loads
from stictiondiag.stiction.fit_details import (
    HammersteinDetails,
    LeastSquaresEstimate,
    MvFitDetails,
    ParameterCounts,
    SegmentStatistics,
)
from stictiondiag.stiction.fit_result import Determinacy

SAMPLES = sorted((Path(__file__).resolve().parents[1] / "sample_data").glob("*.csv"))


@pytest.mark.slow
@pytest.mark.parametrize("path", SAMPLES, ids=lambda p: p.stem)
def test_every_sample_analysis_round_trips(path):
    """Every bundled sample's whole Analysis (replay and gap included) survives
    JSON: the same types back, every number bit for bit (a second encoding of the
    decoded object is the same text)."""
    # The gap diagnosis (the slowest step) on one loop with mv and one without.
    gap = path.stem in ("temperature_quantised", "level_no_mv")
    a = analyze_file(path, config=AnalysisConfig(gap=gap))
    text = a.to_json()
    b = Analysis.from_json(text)
    assert type(b) is Analysis and type(b.fit) is type(a.fit)
    assert b.to_json() == text
    assert b.verdict.status == a.verdict.status and b.fit.S == a.fit.S
    assert type(b.verdict.evidence) is type(a.verdict.evidence)
    assert b.verdict.cause is a.verdict.cause and b.verdict.runner_up is a.verdict.runner_up
    assert np.array_equal(b.tags.pv, a.tags.pv) and b.tags.pv.dtype == a.tags.pv.dtype
    # The summary every renderer reads is the same from the decoded object.
    assert b.to_dict() == a.to_dict()
    for sym in ("S", "J"):
        assert b.fit.determinacy_of(sym) is a.fit.determinacy_of(sym)
    # The fit's diagnostics come back typed, down to their nested parts.
    assert isinstance(a.fit.details, MvFitDetails | HammersteinDetails)
    assert type(b.fit.details) is type(a.fit.details)
    assert type(b.fit.details.n_parameters) is ParameterCounts
    if isinstance(b.fit.details, MvFitDetails):
        assert type(b.fit.details.least_squares) is LeastSquaresEstimate
        assert type(b.fit.details.segments) is SegmentStatistics
    assert (b.gap is None) == (not gap)
    if a.replay is not None:
        assert type(b.replay.process_fit.process) is type(a.replay.process_fit.process)


#: The keys ``details`` of a fit's JSON has always had (schema 11, a dict then), in
#: order: the method's diagnostics, then the typed fields ``StictionFit`` adds.
_MV_DETAILS = [
    "play_width", "bias", "least_squares", "segments", "burn_in_samples", "noise_cost",
    "n_parameters", "effective_samples", "n_samples", "valve_model", "determinacy",
    "interval_method", "block_samples", "block_sse",
]  # fmt: skip
_MV_LEAST_SQUARES = [
    "S", "J", "S_interval", "J_interval", "cost", "cost_by_valve_model",
    "effective_samples", "S_bounded", "J_bounded",
]  # fmt: skip
_MV_SEGMENTS = [
    "S", "J", "S_interval", "J_interval", "S_iqr", "J_iqr", "S_travel_at_reversals",
    "n_slips", "n_used", "n_reversals", "cost", "noise_mv", "noise_op", "quantum_mv",
]  # fmt: skip
_NOMV_DETAILS = [
    "play_width", "row_stride", "rows_left_out", "dead_time_interval_s",
    "linear_valve_dead_time_s", "highpass_corner_s", "search_limit", "fitted_samples",
    "cost_by_valve_model_coarse", "effective_samples", "effective_samples_residual",
    "noise_cost", "explained", "moving_fraction", "J_confounded_with_gain", "n_samples",
    "n_parameters", "n_evaluations",
]  # fmt: skip


@pytest.mark.slow
@pytest.mark.parametrize("stem", ["temperature_quantised", "level_no_mv"])
def test_details_json_keeps_its_keys(stem):
    """The typed ``details`` writes the keys the dict wrote, in the same order
    (one loop with mv, one without)."""
    a = analyze_file(SAMPLES[0].parent / f"{stem}.csv", config=AnalysisConfig(gap=False))
    d = json.loads(json.dumps(a.fit.to_dict()))["details"]
    keys = list(d)
    if stem == "temperature_quantised":
        assert isinstance(a.fit.details, MvFitDetails)
        # The archive resolution is written only where the record has one.
        assert [k for k in keys if k != "resolution"] == _MV_DETAILS
        assert list(d["least_squares"]) == _MV_LEAST_SQUARES
        assert list(d["segments"]) == _MV_SEGMENTS
        assert d["n_parameters"] == {"stiction": 3, "linear": 1}
        assert isinstance(d["least_squares"]["S_interval"], list)
    else:
        assert isinstance(a.fit.details, HammersteinDetails)
        # The typed fields of a fit without mv follow its own diagnostics.
        assert keys[: len(_NOMV_DETAILS)] == _NOMV_DETAILS
        assert "note" not in keys or keys[len(_NOMV_DETAILS)] == "note"
        assert isinstance(d["dead_time_interval_s"], list) and len(d["fitted_samples"]) == 2


def test_encoding_covers_what_results_hold():
    @dataclasses.dataclass(frozen=True)
    class _Local:  # not importable by name: encode works, decode is refused below
        x: float

    value = {
        "a": np.arange(6, dtype=np.int32).reshape(2, 3),
        "t": (1, 2.5, None),
        "nan": math.nan,
        "inf": -math.inf,
        "e": Determinacy.OPEN,
        "n": np.float64(0.1) + np.float64(0.2),
    }
    back = decode(json.loads(json.dumps(encode(value), allow_nan=False)))
    assert back["a"].dtype == np.int32 and back["a"].shape == (2, 3)
    assert np.array_equal(back["a"], value["a"])
    assert back["t"] == (1, 2.5, None) and math.isnan(back["nan"]) and back["inf"] == -math.inf
    assert back["e"] is Determinacy.OPEN
    assert back["n"] == 0.30000000000000004  # repr round trip: bit for bit
    with pytest.raises(DataError, match="outside stictiondiag"):
        decode(encode(_Local(1.0)))
    with pytest.raises(DataError, match="unknown class"):
        decode({"$type": "stictiondiag.core.schema:Nothing"})


def test_foreign_and_newer_documents_are_refused():
    text = dumps({"x": 1}, schema="stictiondiag.analysis")
    assert loads(text, schema="stictiondiag.analysis") == {"x": 1}
    with pytest.raises(DataError, match="not a other result file"):
        loads(text, schema="other")
    newer = json.dumps({"schema": "s", "version": SCHEMA_VERSION + 1, "result": None})
    with pytest.raises(DataError, match="upgrade"):
        loads(newer, schema="s")
    older = json.dumps({"schema": "s", "version": SCHEMA_VERSION - 1, "result": None})
    with pytest.raises(DataError, match="analyse the record again"):
        loads(older, schema="s")
    evil = json.dumps({"schema": "s", "version": SCHEMA_VERSION, "result": {"$type": "os:system"}})
    with pytest.raises(DataError, match="outside stictiondiag"):
        loads(evil, schema="s")
    with pytest.raises(DataError, match="not a result file"):
        loads("{", schema="s")


def test_summary_gives_the_clock_time_of_the_first_sample():
    """``tags.start`` in the JSON is the export's clock time of the first sample
    (ISO 8601, UTC), so the report can say "from <start>"; None without dates."""
    from stictiondiag.analysis import analyze
    from stictiondiag.io.tags import Tags, read_tags

    path = next(p for p in SAMPLES if p.stem == "level_undershoot")  # stamps from 2004-03-01
    tags = read_tags(path)
    d = analyze(tags, config=AnalysisConfig(gap=False, replay=False)).to_dict()
    assert d["tags"]["start"] == "2004-03-01T00:00:00+00:00"
    bare = Tags.from_arrays(tags.pv, tags.op, mv=tags.mv, ts=tags.ts, loop_type="level")
    d = analyze(bare, config=AnalysisConfig(gap=False, replay=False)).to_dict()
    assert d["tags"]["start"] is None
