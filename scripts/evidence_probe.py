"""What limits the evidence of the fit without mv, measured on the simulated family.

    python scripts/evidence_probe.py [--cache /tmp/stiction_family] [--n-rich 120] [--workers 2]

Two questions, simulated loops only (no real-plant record, no ISDB label):

1. **Does the label hide a separable class?**  The family labels every valve with
   friction sticky, whatever the record shows.  Each sticky loop has a twin with a
   linear valve (same process, tuning, loads, set point); ``stiction_share`` is the
   variance of the difference of their noise-free pv over the recorded pv's
   (:func:`stictiondiag.apps.family.stiction_share`).  The script prints the area
   under the ROC curve of the fit's features, sticky against healthy, by that share;
   then refits the probability model with the label "friction that accounts for at
   least :data:`MATERIAL` of pv's variance" (the verdict's own materiality level,
   :data:`stictiondiag.stiction.verdict.MIN_IMPROVEMENT`) and prints its held-out
   reliability and how many loops it leaves between the decision levels.
2. **Is the linear part too stiff?**  The improvement compares the stiction valve
   with a linear valve through a first-order process.  If healthy loops gained
   improvement because that process is too stiff for closed-loop data, a richer
   linear part (four time constants, gains of one sign: a monotone step response)
   given to both valves would take it away.  On ``--n-rich`` healthy loops and as
   many sticky ones with S above 0.4 of op's 5-95 % spread (loops without mv of the
   training draw), the script prints the improvement's area under the ROC curve with
   the fitted first-order part and with the richer part (the stiction valve held at
   its fitted S and J), by loop kind.

3. **Do healthy loops gain from the overshoot case?**  The healthy loops' best fits
   often have J several times S (the overshoot case of Section 5.1, J > S; with S
   near 0 a jump at every reversal of op).  The same loops are fitted with the
   search held to J <= S (grid points with J > S dropped, for this probe only) and
   the improvement's separation printed beside the free search's.

4. **Would a prediction-error comparison resist the feedback?**  The gap's process
   replay (:func:`stictiondiag.identification.predictor.fit_predictor`) tracks the
   load with a Kalman filter and is judged at a prediction horizon, which the plain
   output-error fit is not.  On the same loops, the replay is fitted to pv twice,
   driven by op (a linear valve) and by the Hammerstein fit's valve output, and the
   relative drop of its squared error is printed beside the fit's improvement.

5. **How far could a null fitted to each loop go?**  Parts 2 to 4 change the fit.
   An upper bound for any test that calibrates the improvement loop by loop (for
   example, against surrogate records of the same loop with a linear valve): the
   fit's improvement on each sticky loop of the sample against that on its exact
   twin with a linear valve (:func:`stictiondiag.apps.family.family_loop` with
   ``twin=True``: same loads, noise and recording).  No real test knows the twin.

The features come from the cache of ``scripts/train_probability.py`` (computed there
if missing); the shares and the richer fits are computed here.
"""

from __future__ import annotations

import argparse
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from probability_features import family_features  # noqa: E402
from probability_fit import _fit_predict, reliability, roc_auc  # noqa: E402

from stictiondiag.analysis import estimate_stiction  # noqa: E402
from stictiondiag.apps.family import family_loop  # noqa: E402
from stictiondiag.core.errors import StictionError  # noqa: E402
from stictiondiag.identification.predictor import fit_predictor  # noqa: E402
from stictiondiag.stiction.hammerstein import fit as hs  # noqa: E402
from stictiondiag.stiction.hammerstein import search as hsearch  # noqa: E402
from stictiondiag.stiction.hammerstein.columns import lag, regressors  # noqa: E402
from stictiondiag.stiction.hammerstein.kernels import same_sign_lstsq, valve_run  # noqa: E402
from stictiondiag.stiction.hammerstein.search import fit_linear  # noqa: E402
from stictiondiag.stiction.probability import PART_FEATURES  # noqa: E402
from stictiondiag.stiction.valvefit import ValveVariant  # noqa: E402

#: Share of pv's variance above which the friction counts as material [-].
MATERIAL = 0.1

#: Strata of the stiction share for the area table [-].
SHARE_STRATA = ((0.0, 0.02), (0.02, 0.1), (0.1, 0.3), (0.3, np.inf))

#: Features whose separation the first probe prints.
PROBE_FEATURES = ("improvement", "support", "halves_improvement", "oscillating")


def _share(seed: int) -> tuple[int, float]:
    return seed, float(family_loop(seed).truth["stiction_share"])


def shares(rows: list[dict], workers: int) -> dict[int, float]:
    seeds = [r["seed"] for r in rows if r["sticky"]]
    with ProcessPoolExecutor(workers) as pool:
        return dict(pool.map(_share, seeds, chunksize=8))


def share_table(rows: list[dict], share: dict[int, float]) -> list[str]:
    out = []
    for mv in (False, True):
        part = [r for r in rows if r["has_mv"] == mv]
        healthy = [r for r in part if not r["sticky"]]
        out.append(f"loops {'with' if mv else 'without'} mv ({len(healthy)} healthy):")
        for lo, hi in SHARE_STRATA:
            sticky = [r for r in part if r["sticky"] and lo <= share[r["seed"]] < hi]
            if not sticky:
                continue
            y = np.array([1] * len(sticky) + [0] * len(healthy), bool)
            cells = [
                f"{f} {roc_auc(y, np.array([r['features'][f] for r in sticky + healthy])):.2f}"
                for f in PROBE_FEATURES
            ]
            out.append(f"  share {lo:g}-{hi:g} ({len(sticky)} sticky): " + ", ".join(cells))
    return out


def relabelled(train, test, share) -> list[str]:
    def label(r):
        return float(r["sticky"] and share[r["seed"]] >= MATERIAL)

    out = []
    for name, lab in (
        ("any friction (shipped)", lambda r: float(r["sticky"])),
        ("material", label),
    ):
        p = _fit_predict(train, test, PART_FEATURES, label=lab)
        y = np.array([lab(r) for r in test])
        no_mv = np.array([not r["has_mv"] for r in test])
        undecided = int(np.sum(no_mv & (p > 0.3) & (p < 0.7)))
        worst = max(abs(b["observed"] - b["mean_p"]) for b in reliability(p, y) if b["n"])
        called, cleared = p > 0.7, p < 0.3
        out.append(
            f"label {name}: positives {y.mean():.2f} of held-out loops; without mv"
            f" {undecided} of {int(no_mv.sum())} between 0.3 and 0.7; calls right"
            f" {np.mean(y[called] == 1):.2f} of {int(called.sum())} stiction,"
            f" {np.mean(y[cleared] == 0):.2f} of {int(cleared.sum())} no stiction;"
            f" worst band gap {worst:.3f}"
        )
    return out


def _searched(tags):
    """The Hammerstein fit's setup, start, search points and range of time constants
    on ``tags`` (as :func:`stictiondiag.stiction.hammerstein.fit_hammerstein` runs
    them), or None where the fit refuses the record."""
    op, pv, dt = hs._check(tags.op, tags.pv, float(tags.ts))
    op, pv = op[: hs.MAX_SAMPLES], pv[: hs.MAX_SAMPLES]
    try:
        setup = hs._setup(op, pv, dt, bool(tags.integrating), None)
        start, search, _, tau_range = hs._search(setup)
    except StictionError:
        return None
    return setup, start, search, tau_range


def _fitted(tags):
    """The Hammerstein fit of ``tags`` (a record without mv) as ``analyze`` runs it
    (:func:`stictiondiag.analysis.estimate_stiction`); None where it refuses."""
    try:
        return estimate_stiction(tags)
    except StictionError:
        return None


def _rich_cost(prob, u, taus, delays) -> float:
    """Least cost of the linear part with four time constants (gains of one sign)."""
    uf = lag(u, prob.pre_lag, prob.k_start) if prob.pre_lag > 0 else u
    phis = [regressors(uf, float(t), prob.a_hp, prob.k_start) for t in taus]
    gains = [phis[0][:, 0]] + [phi[:, 1] for phi in phis]
    X0 = np.column_stack(gains + [phis[0][:, 2], phis[0][:, 3], phis[0][:, 4]])
    best = np.inf
    for d in delays:
        X, y = X0[prob.rows], prob.yf[prob.rows + int(d)]
        theta = same_sign_lstsq(X, y, len(gains))
        best = min(best, float(np.sum((y - X @ theta) ** 2)))
    return best


def _rich_one(seed: int) -> dict | None:
    loop = family_loop(seed)
    found = _searched(loop.tags())
    if found is None:
        return None
    setup, start, search, tau_range = found
    prob = setup.problem
    S_all, J_all, C_all, D_all, O_all, T_all = search.arrays()
    i = int(np.argmin(C_all))
    S, J, cost, offset, tau = (float(v[i]) for v in (S_all, J_all, C_all, O_all, T_all))
    delay = int(D_all[i])
    lin_cost, lin_delay, _ = fit_linear(setup, tau, tau_range)
    variant = start.variant.for_band(S)
    u, _ = valve_run(
        prob._input(variant),
        float(variant.model_S(S)),
        J,
        variant.kano,
        prob.k_start,
        prob.d_start,
        offset,
    )
    taus = np.geomspace(max(0.3, setup.period * 0.02), float(setup.period), 4)

    def around(d):
        return sorted(
            {int(np.clip(round(f * max(d, 1)), 1, setup.d_max)) for f in (0.5, 0.75, 1, 1.5, 2)}
        )

    rich_lin = _rich_cost(prob, prob._input(ValveVariant("linear", False)), taus, around(lin_delay))
    rich_st = _rich_cost(prob, u, taus, around(delay))
    return {
        "sticky": loop.sticky,
        "kind": loop.truth["kind"],
        "improvement": 1.0 - cost / lin_cost,
        "improvement_rich": 1.0 - rich_st / rich_lin,
    }


def _overshoot_one(args) -> dict | None:
    """Improvement of the free search and of the search held to J <= S."""
    seed, held = args
    if held:
        free_grid = hsearch.grid

        def held_grid(S_lo, S_hi, J_lo, J_hi, n):
            SS, JJ, ds, dj = free_grid(S_lo, S_hi, J_lo, J_hi, n)
            keep = JJ <= SS + 1e-12
            keep = keep if keep.any() else JJ == JJ.min()
            return SS[keep], JJ[keep], ds, dj

        hsearch.grid = held_grid  # this worker process only
    loop = family_loop(seed)
    found = _searched(loop.tags())
    if found is None:
        return None
    setup, _, search, tau_range = found
    S_all, J_all, C_all, _, _, T_all = search.arrays()
    ok = J_all <= S_all + 1e-9 if held else np.ones(S_all.size, bool)
    ok = ok if ok.any() else J_all == J_all.min()
    i = np.flatnonzero(ok)[int(np.argmin(C_all[ok]))]
    lin_cost, _, _ = hsearch.fit_linear(setup, float(T_all[i]), tau_range)
    return {
        "sticky": loop.sticky,
        "kind": loop.truth["kind"],
        "improvement": 1.0 - float(C_all[i]) / lin_cost,
    }


def overshoot_table(seeds: list[int], workers: int) -> list[str]:
    res = {}
    for held in (False, True):
        # a fresh pool per setting: the held grid is patched into its workers only
        with ProcessPoolExecutor(workers) as pool:
            res[held] = [r for r in pool.map(_overshoot_one, [(s, held) for s in seeds]) if r]
    out = []
    for kind in ("all", "flow", "self", "integrating", "slave"):
        cells = []
        for held in (False, True):
            sel = [r for r in res[held] if kind == "all" or r["kind"] == kind]
            y = np.array([r["sticky"] for r in sel], bool)
            imp = np.array([r["improvement"] for r in sel])
            cells.append(
                f"{'J <= S' if held else 'free'}: area {roc_auc(y, imp):.2f}, healthy median"
                f" {np.median(imp[~y]):.3f}, sticky median {np.median(imp[y]):.3f}"
            )
        out.append(f"  {kind}: " + "; ".join(cells))
    return out


def _pe_one(seed: int) -> dict | None:
    loop = family_loop(seed)
    tags = loop.tags()
    dt = float(tags.ts)
    fit = _fitted(tags)
    if fit is None:
        return None
    pv, w = np.asarray(tags.pv, float), np.ones(tags.pv.size)
    sse = {}
    for name, u in (("linear", tags.op), ("stiction", fit.mv_model)):
        rep = fit_predictor(np.asarray(u, float), pv, dt, w, cache={})
        sse[name] = float(np.sum((rep.prediction.pv - pv) ** 2))
    return {
        "sticky": loop.sticky,
        "kind": loop.truth["kind"],
        "improvement": fit.improvement,
        "improvement_pe": 1.0 - sse["stiction"] / sse["linear"],
    }


def pe_table(seeds: list[int], workers: int) -> list[str]:
    with ProcessPoolExecutor(workers) as pool:
        res = [r for r in pool.map(_pe_one, seeds, chunksize=4) if r]
    out = []
    for kind in ("all", "flow", "self", "integrating", "slave"):
        sel = [r for r in res if kind == "all" or r["kind"] == kind]
        y = np.array([r["sticky"] for r in sel], bool)
        pe = np.array([r["improvement_pe"] for r in sel])
        a = roc_auc(y, np.array([r["improvement"] for r in sel]))
        out.append(
            f"  {kind}: area of the fit's improvement {a:.2f}, of the replay's"
            f" {roc_auc(y, pe):.2f} (median healthy {np.median(pe[~y]):.3f},"
            f" sticky {np.median(pe[y]):.3f})"
        )
    return out


def _twin_one(seed: int) -> dict | None:
    out = {}
    for twin in (False, True):
        loop = family_loop(seed, twin=twin)
        fit = _fitted(loop.tags())
        if fit is None:
            return None
        out["twin" if twin else "sticky"] = fit.improvement
        out["kind"] = loop.truth["kind"]
    return out


def twin_table(seeds: list[int], workers: int) -> list[str]:
    with ProcessPoolExecutor(workers) as pool:
        res = [r for r in pool.map(_twin_one, seeds, chunksize=4) if r]
    out = []
    for kind in ("all", "flow", "self", "integrating", "slave"):
        sel = [r for r in res if kind == "all" or r["kind"] == kind]
        a, b = np.array([r["sticky"] for r in sel]), np.array([r["twin"] for r in sel])
        y = np.r_[np.ones(a.size), np.zeros(b.size)].astype(bool)
        out.append(
            f"  {kind} ({a.size} pairs): improvement median {np.median(a):.3f} sticky,"
            f" {np.median(b):.3f} twin; sticky above its twin in {np.mean(a > b):.2f},"
            f" by more than 0.05 in {np.mean(a > b + 0.05):.2f}; area {roc_auc(y, np.r_[a, b]):.2f}"
        )
    return out


def probe_seeds(train: list[dict], n: int) -> list[int]:
    """``n`` healthy loops without mv and ``n`` sticky ones with S above 0.4 of op's
    5-95 % spread, drawn from the training loops (seed 0)."""
    rng = np.random.default_rng(0)
    rows = [r for r in train if not r["has_mv"]]
    healthy = [r["seed"] for r in rows if not r["sticky"]]
    sticky = [
        r["seed"] for r in rows if r["sticky"] and r["truth"]["S"] / max(r["op_spread"], 1e-9) > 0.4
    ]
    seeds = list(rng.choice(healthy, min(n, len(healthy)), replace=False))
    seeds += list(rng.choice(sticky, min(n, len(sticky)), replace=False))
    return [int(s) for s in seeds]


def rich_table(seeds: list[int], workers: int) -> list[str]:
    with ProcessPoolExecutor(workers) as pool:
        res = [r for r in pool.map(_rich_one, seeds, chunksize=4) if r]
    out = []
    for kind in ("all", "flow", "self", "integrating", "slave"):
        sel = [r for r in res if kind == "all" or r["kind"] == kind]
        y = np.array([r["sticky"] for r in sel], bool)
        if y.sum() < 3 or (~y).sum() < 3:
            continue
        a = roc_auc(y, np.array([r["improvement"] for r in sel]))
        b = roc_auc(y, np.array([r["improvement_rich"] for r in sel]))
        out.append(
            f"  {kind} ({int((~y).sum())} healthy, {int(y.sum())} sticky): area of the"
            f" improvement {a:.2f} with the first-order part, {b:.2f} with the richer one"
        )
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cache", type=Path, default=Path("/tmp/stiction_family"))
    ap.add_argument("--n-train", type=int, default=1200)
    ap.add_argument("--n-test", type=int, default=400)
    ap.add_argument("--n-rich", type=int, default=120)
    ap.add_argument("--workers", type=int, default=2)
    a = ap.parse_args(argv)
    train = family_features(1, a.n_train, a.cache, a.workers)
    test = family_features(2, a.n_test, a.cache, a.workers)
    share = shares(train + test, a.workers)
    st = np.array([share[r["seed"]] for r in train + test if r["sticky"]])
    q = np.quantile(st, [0.1, 0.25, 0.5, 0.75, 0.9])
    print(f"stiction share of the sticky loops, 10/25/50/75/90 %: {np.round(q, 3).tolist()}")
    print(
        f"sticky loops whose friction is material (share >= {MATERIAL}): {np.mean(st >= MATERIAL):.2f}"
    )
    print("\n".join(share_table(train + test, share)))
    print("\n".join(relabelled(train, test, share)))
    seeds = probe_seeds(train, a.n_rich)
    print("richer linear part:")
    print("\n".join(rich_table(seeds, a.workers)))
    print("search held to J <= S:")
    print("\n".join(overshoot_table(seeds, a.workers)))
    print("prediction-error replay:")
    print("\n".join(pe_table(seeds, a.workers)))
    print("each sticky loop against its linear twin:")
    print("\n".join(twin_table(seeds[len(seeds) // 2 :], a.workers)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
