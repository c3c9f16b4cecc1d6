"""One calibrated stiction probability per loop.

The evidence of the analysis (Choudhury, Thornhill & Shah 2005, Section 5.3: is there
a limit cycle, and does the stiction model explain it better than a linear valve) and
of the classic detection tests is reduced to a handful of well-defined numbers,
:data:`FEATURES`, and combined by a regularised logistic regression into
``P(stiction)``:

``improvement``
    Share of the linear valve's residual the stiction model removes,
    ``1 - SSE_stiction / SSE_linear``, clipped to [-0.5, 1] [-].
``support``
    Block-bootstrap share of one-cycle resamples in which that improvement exceeds
    :data:`~stictiondiag.stiction.verdict.MIN_IMPROVEMENT` (how consistently over the
    cycles the stiction model does better) [-].
``s_excludes_zero``, ``s_open``
    The S interval's lower end is above 0; its upper end reaches the search limit
    (1 or 0).
``s_low_share``
    The lower end of the S interval over the spread of op (5 to 95 % quantiles),
    clipped to [0, 2]: a sticky valve makes op travel at least S between slips, and
    only the S the data insist on counts (0 when S cannot be told from 0, however
    large the fitted S is against an op that hardly moves) [-].
``oscillating``, ``regularity``
    A regular oscillation in pv (or the control error) or op (Thornhill et al. 2003
    test of :func:`stictiondiag.signals.oscillation.detect_oscillation`), and
    ``log(1 + r)`` of the larger regularity r (capped at 20) [-].
``horch``, ``choudhury``, ``he``, ``rossi_scali``, ``kano``
    The calls of the classic tests (:mod:`stictiondiag.stiction.classic`): Horch
    (1999, 2000) cross-correlation or second-derivative test; Choudhury, Shah &
    Thornhill (2004) bicoherence and pv-op ellipse; He et al. (2007) triangle versus
    sine fit (the oscillation's shape); Rossi & Scali (2005) relay versus sine fit;
    Kano et al. (2004) stuck sections (pv as the valve's proxy in flow loops).  +1
    stiction, -1 no stiction, 0 undecided or not applicable.
``short_record``
    The record holds fewer cycles than the oscillation test needs (1 or 0).
``halves_s_low``, ``halves_s_agree``, ``halves_improvement``, ``halves_missing``
    The steadiness of the estimate over the record: the Hammerstein fit repeated on
    each half of the record (same cycle period).  A sticky valve keeps its S from
    one half to the next (the friction is a property of the valve, Section 5.1), a
    linear valve's fitted S wanders with the noise and the loads.  Each half's S is
    the lower end of its interval (the S the data insist on, as for
    ``s_low_share``).  The smaller of the two S over the spread of op (clipped to
    [0, 2]), the ratio of the smaller to the larger S (0 when both are 0), the
    smaller of the two improvements (clipped
    to [-0.5, 1]); ``halves_missing`` is 1 when the halves could not be fitted (a
    half shorter than two cycles, or the valve position recorded) and the three
    others are then 0.

``he_si``, ``horch_phase``, ..., ``op_slope_kurtosis``
    The classic tests' continuous statistics and the oscillation's shape
    (:data:`~stictiondiag.stiction.probability_evidence.CONTINUOUS`): He et al.'s
    index, Horch's phase index and second-derivative kurtosis, the bicoherence's NLI
    and NGI, the pv-op ellipse's axis ratio and apparent stiction over op's spread,
    Kano's stuck share, Rossi & Scali's relay-versus-sine score, and the odd
    harmonics and slope kurtosis of pv and op; defined, with their neutral values
    where a test cannot run, in :mod:`stictiondiag.stiction.probability_evidence`.
    Computed for every loop and kept in its record, but not in the model: with them
    the cross-validated log loss on the simulated training loops was lower, the log
    loss on the held-out simulated loops was not (``docs/calibration.md``).

Every feature of :data:`CANDIDATES` is computed for each loop; the model uses
:data:`FEATURES` (:data:`PART_FEATURES`), the set that passed the rule of
``scripts/train_probability.py``: a set ships only if it has the lower log loss on
the held-out simulated loops by more than simulation can resolve, else the simpler
set is kept (``docs/calibration.md``, "Choice of model").

The model is fitted on simulated loops only (:mod:`stictiondiag.apps.family`,
``scripts/train_probability.py``), separately for loops with and without the valve
position recorded (the mv fit compares the valve with its own position, the
Hammerstein fit only through the process), and ships as :data:`MODEL_FILE`; its calibration on held-out
simulated loops is in ``docs/calibration.md``.  Real-plant labels are never used.
"""

from __future__ import annotations

import json
import math
from functools import lru_cache
from pathlib import Path

import numpy as np

from stictiondiag.core.errors import StictionError
from stictiondiag.stiction.classic import classic_features
from stictiondiag.stiction.probability_evidence import (
    CONTINUOUS,
    continuous_features,
    shape_statistics,
)

#: The features of the earlier model (the fit, the oscillation, the classic tests'
#: calls, the split-half fits); computed for every loop.
BASE_FEATURES: tuple[str, ...] = (
    "improvement",
    "support",
    "s_excludes_zero",
    "s_open",
    "s_low_share",
    "oscillating",
    "regularity",
    "horch",
    "choudhury",
    "he",
    "rossi_scali",
    "kano",
    "short_record",
    "halves_s_low",
    "halves_s_agree",
    "halves_improvement",
    "halves_missing",
)

#: Every feature :func:`evidence_features` computes: :data:`BASE_FEATURES` and the
#: continuous statistics of :mod:`stictiondiag.stiction.probability_evidence`.
CANDIDATES: tuple[str, ...] = BASE_FEATURES + CONTINUOUS

#: The classic tests whose calls are computed (as features of :data:`BASE_FEATURES`),
#: by their name in :func:`stictiondiag.stiction.classic.classic_features`
#: (``<test>_call``).
CLASSIC_TESTS = ("horch", "choudhury", "he", "rossi_scali", "kano")

#: The features of the model, in the order of its coefficients: the earlier set.  The
#: continuous statistics are computed and kept in each loop's record, but a feature set
#: ships only if it beats the shipped one in log loss on the held-out simulated loops
#: (not only in cross-validation on the training loops), and the simpler set is kept
#: when simulation cannot tell two apart; the continuous set did not pass
#: (``docs/calibration.md``, "Choice of model"; ``scripts/train_probability.py``).
FEATURES: tuple[str, ...] = BASE_FEATURES

#: The features of each part of the model (loops without mv, ``op_pv``; with mv, ``mv``).
PART_FEATURES: dict[str, tuple[str, ...]] = {"op_pv": BASE_FEATURES, "mv": BASE_FEATURES}

#: The fitted model, written by ``scripts/train_probability.py``.
MODEL_FILE = Path(__file__).with_name("probability_model.json")

#: Largest regularity counted [-] (beyond it a cycle is simply regular).
MAX_REGULARITY = 20.0


def _vote(verdict) -> float:
    return {"stiction": 1.0, "no_stiction": -1.0}.get(str(verdict), 0.0)


def classic_votes(
    op, pv, sp, ts: float, integrating: bool, loop_type: str | None = None, mv=None
) -> dict:
    """The classic tests' calls as numbers: +1 stiction, -1 no stiction, 0 undecided,
    not applicable or not run (a test that cannot run on the record votes 0).

    The tests are those of :mod:`stictiondiag.stiction.classic`
    (:func:`~stictiondiag.stiction.classic.classic_features`); all their statistics are
    returned too, under their own names, with the oscillation's shape in pv and op
    (:func:`~stictiondiag.stiction.probability_evidence.shape_statistics`).
    """
    try:
        feats = classic_features(pv, op, sp, ts, loop_type, integrating=integrating, mv=mv)
    except (StictionError, ValueError, FloatingPointError, np.linalg.LinAlgError):
        feats = {}
    out = {k: (float(v) if v is not None and math.isfinite(v) else None) for k, v in feats.items()}
    out.update(shape_statistics(pv, op, ts, out.get("oscillation_period_s")))
    for test in CLASSIC_TESTS:
        v = feats.get(f"{test}_call")
        out[test] = float(v) if v is not None and math.isfinite(v) else 0.0
    return out


def evidence_features(
    fit,
    oscillation,
    oscillation_op,
    *,
    improvement: float,
    support: float,
    op: np.ndarray,
    classic: dict,
    short_record: bool,
    halves: tuple | None = None,
) -> dict:
    """The features of :data:`CANDIDATES` for one loop (see module doc).

    ``halves`` is ``(S_1, S_2, improvement_1, improvement_2)`` of the fits on the two
    halves of the record [% of span, % of span, -, -], or None.
    """
    S_iv = fit.S_interval
    S_det = fit.determinacy_of("S") if hasattr(fit, "determinacy_of") else None
    S_open = S_det is not None and S_det.open
    q5, q95 = np.percentile(np.asarray(op, dtype=float), [5.0, 95.0])
    spread = float(q95 - q5)
    s_low = float(S_iv[0]) if S_iv is not None else 0.0
    s_low_share = s_low / spread if spread > 0 else 0.0
    regs = [
        float(o.regularity)
        for o in (oscillation, oscillation_op)
        if o is not None and getattr(o, "present", False) and o.regularity is not None
    ]
    osc = any(getattr(o, "present", False) for o in (oscillation, oscillation_op) if o)
    f = {
        "improvement": float(np.clip(improvement, -0.5, 1.0)),
        "support": float(support),
        "s_excludes_zero": float(S_iv is not None and S_iv[0] > 0.0),
        "s_open": float(S_open),
        "s_low_share": float(np.clip(s_low_share if math.isfinite(s_low_share) else 0.0, 0.0, 2.0)),
        "oscillating": float(osc),
        "regularity": math.log1p(min(max(regs), MAX_REGULARITY)) if regs else 0.0,
        **{t: float(classic.get(t, 0.0)) for t in CLASSIC_TESTS},
        "short_record": float(bool(short_record)),
        **halves_features(halves, spread),
        **continuous_features(classic, spread),
    }
    return f


def halves_features(halves: tuple | None, spread: float) -> dict:
    """``halves_*`` features (module doc) from ``(S_1, S_2, improvement_1,
    improvement_2)`` of the two half-record fits and the spread of op [% of span]."""
    if halves is None or not all(math.isfinite(float(v)) for v in halves):
        return {
            "halves_s_low": 0.0,
            "halves_s_agree": 0.0,
            "halves_improvement": 0.0,
            "halves_missing": 1.0,
        }
    s1, s2, f1, f2 = (float(v) for v in halves)
    lo, hi = min(s1, s2), max(s1, s2)
    return {
        "halves_s_low": float(np.clip(lo / spread, 0.0, 2.0)) if spread > 0 else 0.0,
        "halves_s_agree": lo / hi if hi > 0 else 0.0,
        "halves_improvement": float(np.clip(min(f1, f2), -0.5, 1.0)),
        "halves_missing": 0.0,
    }


@lru_cache(maxsize=4)
def load_model(path: str | None = None) -> dict:
    """The fitted model (JSON), cached."""
    p = Path(path) if path else MODEL_FILE
    try:
        model = json.loads(p.read_text())
    except (OSError, ValueError) as exc:
        raise StictionError(
            f"stiction probability model {p} missing or unreadable ({exc}); "
            "run scripts/train_probability.py"
        ) from None
    parts = model.get("parts") or {}
    if tuple(model.get("features", ())) != FEATURES or any(
        tuple(parts.get(name, {}).get("features", ())) != names
        for name, names in PART_FEATURES.items()
    ):
        raise StictionError(f"{p}: its features differ from this version's; retrain it")
    return model


def part_features(model: dict, name: str) -> tuple[str, ...]:
    """The features of part ``name`` of ``model``, in the order of its coefficients
    (the model's ``features`` when the part does not list its own)."""
    part = model["parts"][name]
    return tuple(part.get("features") or model["features"])


def design_row(features: dict, names: tuple[str, ...] = FEATURES) -> np.ndarray:
    """The features as one row in the order of ``names`` (default :data:`FEATURES`)."""
    return np.array([float(features[k]) for k in names])


def logistic(z):
    """``1 / (1 + exp(-z))`` without overflow."""
    z = np.asarray(z, dtype=float)
    return np.where(
        z >= 0, 1.0 / (1.0 + np.exp(-np.abs(z))), np.exp(-np.abs(z)) / (1.0 + np.exp(-np.abs(z)))
    )


def apply_part(part: dict, X: np.ndarray) -> np.ndarray:
    """``P(stiction)`` of the rows of X by one fitted part of the model."""
    X = np.atleast_2d(np.asarray(X, dtype=float))
    z = (X - np.asarray(part["mean"])) / np.asarray(part["scale"])
    return logistic(z @ np.asarray(part["coef"]) + float(part["intercept"]))


def part_name(features: dict, has_mv: bool) -> str:
    """The part of the model that judges a loop: ``mv`` (valve position recorded) or
    ``op_pv``."""
    return "mv" if has_mv else "op_pv"


def stiction_probability(features: dict, has_mv: bool, model: dict | None = None) -> float:
    """Calibrated ``P(stiction)`` of one loop [-] (see module doc)."""
    model = model or load_model()
    name = part_name(features, has_mv)
    part = model["parts"][name]
    return float(apply_part(part, design_row(features, part_features(model, name)))[0])


# --------------------------------------------------------------------------------------
# P in words: what weighed for and against
# --------------------------------------------------------------------------------------

#: Words for each feature's state: (high or 1, low or 0); for the classic tests' calls
#: (stiction, undecided, no stiction).
_FEATURE_WORDS = {
    "improvement": (
        "the stiction model fits much better than a linear valve",
        "the stiction model hardly fits better than a linear valve",
    ),
    "support": (
        "the improvement holds over the cycles",
        "the improvement does not hold over the cycles",
    ),
    "s_excludes_zero": ("S is told apart from 0", "S cannot be told apart from 0"),
    "s_open": ("S's interval reaches the search limit", "S is bounded"),
    "s_low_share": (
        "the smallest S the data allow is a large share of op's travel",
        "the data allow a small or no S compared with op's travel",
    ),
    "oscillating": ("the loop oscillates", "no regular oscillation"),
    "regularity": ("the cycle is regular", "the cycle is irregular"),
    "short_record": ("the record is short", "the record is long enough"),
    "halves_s_low": (
        "each half of the record insists on a large S",
        "one half of the record allows a small or no S",
    ),
    "halves_s_agree": (
        "the two halves of the record insist on the same S",
        "the two halves of the record do not insist on the same S",
    ),
    "halves_improvement": (
        "the stiction model fits better in both halves",
        "the stiction model does not fit better in one half",
    ),
    "halves_missing": ("the halves could not be fitted", "both halves were fitted"),
    "he_si": (
        "the cycle of the integrated signal is triangular (He et al.'s index)",
        "the cycle of the integrated signal is sinusoidal (He et al.'s index)",
    ),
    "horch_phase": (
        "op and pv are out of phase as behind a sticky valve (Horch's index)",
        "op and pv are in phase as behind a linear valve (Horch's index)",
    ),
    "horch_d2_kurtosis": (
        "pv's second derivative is spiky (Horch 2000)",
        "pv's second derivative is smooth (Horch 2000)",
    ),
    "choudhury_nli": (
        "the bicoherence finds the loop nonlinear",
        "the bicoherence finds it linear",
    ),
    "choudhury_ngi": (
        "the control error is non-Gaussian",
        "the control error is near Gaussian",
    ),
    "ellipse_axis_ratio": ("the pv-op plot is an open ellipse", "the pv-op plot is a narrow band"),
    "ellipse_share": (
        "the pv-op ellipse is wide along op",
        "the pv-op ellipse is narrow along op",
    ),
    "kano_rho": ("the valve proxy sticks while op moves", "the valve proxy follows op"),
    "rossi_scali_delta_e": (
        "pv's cycle is relay-like (Rossi & Scali)",
        "pv's cycle is sinusoidal (Rossi & Scali)",
    ),
    "pv_odd_harmonics": ("pv's cycle has strong odd harmonics", "pv's cycle is nearly sinusoidal"),
    "op_odd_harmonics": ("op's cycle has strong odd harmonics", "op's cycle is nearly sinusoidal"),
    "pv_slope_kurtosis": ("pv moves in jumps", "pv moves smoothly"),
    "op_slope_kurtosis": ("op moves in jumps", "op moves smoothly"),
    "pv_amplitude_lock": (
        "pv's cycle keeps its swing while its period wanders, as a stick band makes it",
        "pv's cycle keeps its clock while its swing wanders, as a driven or ringing loop does",
    ),
    "op_amplitude_lock": (
        "op's cycle keeps its swing while its period wanders, as a stick band makes it",
        "op's cycle keeps its clock while its swing wanders, as a driven or ringing loop does",
    ),
    "horch": "Horch's test",
    "choudhury": "the bicoherence test (with its pv-op ellipse)",
    "he": "He et al.'s shape test",
    "rossi_scali": "Rossi & Scali's shape test",
    "kano": "Kano et al.'s stuck-section test",
}

_CALLS = {1.0: "says stiction", -1.0: "says no stiction", 0.0: "is undecided or does not apply"}


def _feature_text(name: str, value: float, mean: float, term: float = 0.0) -> str:
    """Words for one feature's value.  A test's call that pushes the log-odds the
    other way from what it says (the model weighs it against its own call, given
    the evidence it overlaps with) is marked so, not listed bare on the opposite
    side."""
    words = _FEATURE_WORDS[name]
    if isinstance(words, str):
        call = float(value)
        text = f"{words} {_CALLS.get(call, 'is undecided')}"
        if call != 0.0 and call * term < 0:
            text += " (weighed the other way, given the evidence it overlaps with)"
        return text
    if name == "regularity" and value == 0.0:
        return "no cycle whose regularity could be measured"
    binary = name in ("s_excludes_zero", "s_open", "oscillating", "short_record", "halves_missing")
    high = value > 0.5 if binary else value > mean
    return words[0 if high else 1]


def contributions(features: dict, has_mv: bool, model: dict) -> list[tuple[str, float, str]]:
    """Why P is what it is: each feature's term in the log-odds relative to the
    training mean, with its words, largest first."""
    name = part_name(features, has_mv)
    part = model["parts"][name]
    terms = []
    for i, k in enumerate(part_features(model, name)):
        t = part["coef"][i] * (features[k] - part["mean"][i]) / part["scale"][i]
        terms.append((k, float(t), _feature_text(k, features[k], part["mean"][i], t)))
    return sorted(terms, key=lambda kv: -abs(kv[1]))


def evidence_words(contrib: list[tuple[str, float, str]], sign: int, n: int = 3) -> str:
    """The ``n`` largest terms of :func:`contributions` that push P up (``sign`` +1)
    or down (-1), in words."""
    words = [w for _, t, w in contrib if t * sign > 0.05]
    return "; ".join(words[:n]) if words else "nothing in particular"
