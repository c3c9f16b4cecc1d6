"""Whole-plant historian exports built from 16 ISDB loops, in the shapes historians write.

    python scripts/make_isdb_plant.py OUT [--isdb ../shared/data/isdb]

writes into OUT (never into the repository: the ISDB has no open licence):

* ``plant_wide.csv``: ``Timestamp, FIC101.PV, FIC101.OP, FIC101.SP, ...``, one row per
  time stamp of any loop (each loop at its own sample time, empty elsewhere);
* ``plant_long.csv``: ``timestamp, tag, value``, every sample;
* ``plant_long_compressed.csv``: the "recorded values" of a compressing historian:
  pv and op through a swinging door with a deviation of 0.2 % of the tag's range
  (Bristol 1990), sp through an exception deadband of 0.2 % of its range (a constant
  sp is two rows);
* ``plant_wide_compressed.csv``: the same archive as a wide file, empty cells where a
  tag was not archived;
* ``plant_yokogawa.csv``: the wide file in Yokogawa CENTUM naming (``.PV``, ``.MV`` for
  the controller output, ``.SV``).

Each loop gets an ISA tag from its ISDB loop type (FIC flow, LIC level, PIC pressure,
TIC temperature, AIC analyser/concentration) and a number; ``tags.csv`` maps tags to
ISDB loops.  The records start together at 2024-03-01 00:00 UTC.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from stictiondiag.io.compression import exception_compress, swinging_door  # noqa: E402

#: The 16 ISDB loops (sampled at 20 s or faster, at most 8 h long, with sp).
LOOPS = (
    "CHEM1",
    "CHEM2",
    "CHEM6",
    "CHEM10",
    "CHEM11",
    "CHEM12",
    "CHEM13",
    "CHEM17",
    "CHEM23",
    "CHEM24",
    "CHEM26",
    "CHEM28",
    "CHEM32",
    "PAP2",
    "PAP3",
    "PAP9",
)

_ISA = {
    "flow": "FIC",
    "level": "LIC",
    "pressure": "PIC",
    "temperature": "TIC",
    "analyser": "AIC",
    "concentration": "AIC",
}

#: Compression deviation and deadband [share of the tag's range].
DEVIATION = 0.002

START = pd.Timestamp("2024-03-01")


def loops(isdb: Path) -> list[dict]:
    """The loops: tag, ISDB name, sample time [s], and the pv, op, sp arrays."""
    manifest = pd.read_csv(isdb / "manifest.csv").set_index("loop")
    out = []
    for k, name in enumerate(LOOPS):
        row = manifest.loc[name]
        data = pd.read_csv(isdb / row["file"])
        out.append(
            {
                "tag": f"{_ISA[row['loop_type']]}{101 + k}",
                "isdb": name,
                "ts": float(row["ts_s"]),
                "pv": data["pv"].to_numpy(float),
                "op": data["op"].to_numpy(float),
                "sp": data["sp"].to_numpy(float),
            }
        )
    return out


def _archive(loop: dict, role: str) -> np.ndarray:
    values = loop[role]
    seconds = np.arange(values.size) * loop["ts"]
    width = DEVIATION * max(float(np.ptp(values)), 1e-12)
    if role == "sp":
        return exception_compress(values, width)
    return swinging_door(seconds, values, width)


def long_frame(
    all_loops: list[dict], compressed: bool, suffixes: dict, start: pd.Timestamp = START
) -> pd.DataFrame:
    parts = []
    for loop in all_loops:
        for role in ("pv", "op", "sp"):
            values = loop[role]
            index = _archive(loop, role) if compressed else np.arange(values.size)
            stamps = start + pd.to_timedelta(index * loop["ts"], unit="s")
            parts.append(
                pd.DataFrame(
                    {
                        "timestamp": stamps,
                        "tag": loop["tag"] + suffixes[role],
                        "value": values[index],
                    }
                )
            )
    return pd.concat(parts, ignore_index=True).sort_values("timestamp", kind="stable")


def wide_frame(long: pd.DataFrame) -> pd.DataFrame:
    wide = long.pivot_table(index="timestamp", columns="tag", values="value", aggfunc="first")
    wide = wide.reset_index().rename(columns={"timestamp": "Timestamp"})
    wide.columns.name = None
    return wide


def build(isdb: Path, out: Path, start: pd.Timestamp = START) -> dict[str, Path]:
    """Write the five exports and ``tags.csv``; returns name -> path.  ``start`` is the
    records' clock start (exports of later periods for a history of scans)."""
    out.mkdir(parents=True, exist_ok=True)
    all_loops = loops(isdb)
    plain = {"pv": ".PV", "op": ".OP", "sp": ".SP"}
    yokogawa = {"pv": ".PV", "op": ".MV", "sp": ".SV"}
    long = long_frame(all_loops, False, plain, start)
    compressed = long_frame(all_loops, True, plain, start)
    frames = {
        "plant_wide": wide_frame(long),
        "plant_long": long,
        "plant_long_compressed": compressed,
        "plant_wide_compressed": wide_frame(compressed),
        "plant_yokogawa": wide_frame(long_frame(all_loops, False, yokogawa, start)),
    }
    paths = {}
    for name, frame in frames.items():
        paths[name] = out / f"{name}.csv"
        frame.to_csv(paths[name], index=False, date_format="%Y-%m-%d %H:%M:%S")
    pd.DataFrame(
        [
            {"tag": lp["tag"], "isdb": lp["isdb"], "ts_s": lp["ts"], "n": lp["pv"].size}
            for lp in all_loops
        ]
    ).to_csv(out / "tags.csv", index=False)
    return paths


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path)
    parser.add_argument("--isdb", type=Path, default=ROOT.parent / "shared" / "data" / "isdb")
    parser.add_argument("--start", default=str(START), help="clock start of the records")
    args = parser.parse_args()
    for name, path in build(args.isdb, args.out, pd.Timestamp(args.start)).items():
        print(f"{name}: {path} ({path.stat().st_size / 1e6:.1f} MB)")


if __name__ == "__main__":
    main()
