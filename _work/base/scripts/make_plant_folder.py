"""Write a plant folder from the sample loops: the input of ``stiction scan`` at plant scale.

From ``sample_data/*.csv`` (six simulated loops, see sample_data/README.md):

* ``plant_wide.csv``: one wide historian export with six loops on one clock, tags
  grouped by prefix and named in mixed styles (``FIC101.PV``, ``LIC-200.OP``,
  ``TIC_400.PV``, ``Loop6 PV``...); each loop's own samples, one per row (rows past a
  loop's end empty);
* ``plant_long.parquet``: the same six loops as a long ``timestamp, tag, value`` table,
  each tag on its own clock (the loop's sampling);
* the broken loop, in the wide file: ``FIC900.PV`` without its op;
* ``loops.csv``: the loops manifest (``loop, ts``) with each loop's sampling time
  (the wide file's clock is a sample count); the loop types are left to the tags
  and the data.

The file ``expected.json`` lists, per loop, the sample file it came from, the options
that analyse it by hand, the loop type the tags or the data should give and whether
it integrates.

Usage: ``python scripts/make_plant_folder.py OUT`` (default ``plant``).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = ROOT / "sample_data"

#: (sample file, loop name, tag style, loop type by hand, loop type inferred, integrating).
#: ``Loop6`` has no ISA tag: the data tell it integrates, not that it is a level.
LOOPS = (
    ("healthy_flow.csv", "FIC101", "{p}.{r}", "flow", "flow", False),
    ("level_undershoot.csv", "LIC-200", "{p}.{r}", "level", "level", True),
    ("flow_mixed.csv", "FC_301", "{p}_{r}", "flow", "flow", False),
    ("temperature_quantised.csv", "TIC400", "{p}.{r}", "temperature", "temperature", False),
    ("slave_flow_stickslip.csv", "FIC501", "{p}:{r}", "flow", "flow", False),
    ("level_no_mv.csv", "Loop6", "{p} {r}", "level", "other", True),
)

ROLE_NAMES = {"pv": "PV", "op": "OP", "mv": "MV", "sp": "SP"}


def _roles(frame: pd.DataFrame) -> dict[str, np.ndarray]:
    out = {}
    for role in ("sp", "pv", "op", "mv"):
        hit = [c for c in frame.columns if c.lower() == role or c.lower().endswith(f".{role}")]
        if role == "sp":
            hit = hit or [c for c in frame.columns if c.lower().endswith(".sv")]
        if hit:
            out[role] = frame[hit[0]].to_numpy(dtype=float)
    return out


def _ts(name: str) -> float:
    frame = pd.read_csv(SAMPLES / name, nrows=3)
    first = frame.columns[0]
    if first.lower() == "timestamp":
        stamps = pd.to_datetime(frame[first])
        return float((stamps.iloc[1] - stamps.iloc[0]).total_seconds())
    return float(frame[first].iloc[1] - frame[first].iloc[0])


def make_plant_folder(out: Path) -> dict:
    """Write the plant folder (module docstring) and return the expected outcome."""
    out.mkdir(parents=True, exist_ok=True)
    wide: dict[str, np.ndarray] = {}
    long_parts = []
    expected: dict = {}
    manifest = []
    t0 = pd.Timestamp("2024-01-01")
    for name, prefix, style, by_hand, inferred, integrating in LOOPS:
        frame = pd.read_csv(SAMPLES / name)
        ts = _ts(name)
        roles = _roles(frame)
        for role, values in roles.items():
            tag = style.format(p=prefix, r=ROLE_NAMES[role])
            wide[tag] = values
            stamps = t0 + pd.to_timedelta(np.arange(values.size) * ts, unit="s")
            long_parts.append(pd.DataFrame({"timestamp": stamps, "tag": tag, "value": values}))
        expected[prefix] = {
            "file": name,
            "options": {"loop_type": by_hand},
            "loop_type": inferred,
            "integrating": integrating,
            "ts": ts,
        }
        manifest.append({"loop": prefix, "ts": ts})
    # The broken loop: a pv recorded without its controller's output.
    wide["FIC900.PV"] = pd.read_csv(SAMPLES / "healthy_flow.csv")["pv"].to_numpy()
    n = max(v.size for v in wide.values())
    table = pd.DataFrame(
        {"sample": np.arange(n)}
        | {k: np.concatenate([v, np.full(n - v.size, np.nan)]) for k, v in wide.items()}
    )
    table.to_csv(out / "plant_wide.csv", index=False, float_format="%.10g")
    pd.concat(long_parts, ignore_index=True).to_parquet(out / "plant_long.parquet", index=False)
    pd.DataFrame(manifest).to_csv(out / "loops.csv", index=False)
    (out / "expected.json").write_text(json.dumps(expected, indent=1) + "\n")
    return expected


if __name__ == "__main__":
    target = Path(sys.argv[1] if len(sys.argv) > 1 else "plant")
    make_plant_folder(target)
    print(f"wrote {target}")
