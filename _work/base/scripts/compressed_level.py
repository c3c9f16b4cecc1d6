"""S and J of the bundled level loop exported as a compressed historian archive.

    python scripts/compressed_level.py

The loop ``sample_data/level_undershoot.csv`` (true S = 5 %, J = 2.5 %) is written as a
long "recorded values" export through each compression of
:mod:`stictiondiag.io.compression` and analysed (no gap diagnosis); one line per case
with the samples read, the reconstruction chosen per tag and S, J.
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from stictiondiag import AnalysisConfig, analyze  # noqa: E402
from stictiondiag.io.compression import exception_compress, swinging_door  # noqa: E402
from stictiondiag.io.plant import plant_loops, read_plant_loop  # noqa: E402

CASES = {
    "plain (every sample)": lambda t, v: np.arange(v.size),
    "PI exception 0.1 (previous value sent)": lambda t, v: exception_compress(v, 0.1, True),
    "swinging door 0.1": lambda t, v: swinging_door(t, v, 0.1),
    "swinging door 0.3": lambda t, v: swinging_door(t, v, 0.3),
    "deadband 0.05, held": lambda t, v: exception_compress(v, 0.05),
    "deadband 0.1, held": lambda t, v: exception_compress(v, 0.1),
}


def main() -> None:
    frame = pd.read_csv(ROOT / "sample_data" / "level_undershoot.csv", parse_dates=["Timestamp"])
    seconds = (frame["Timestamp"] - frame["Timestamp"][0]).dt.total_seconds().to_numpy()
    with tempfile.TemporaryDirectory() as tmp:
        for name, keep in CASES.items():
            parts = []
            for tag in frame.columns[1:]:
                index = keep(seconds, frame[tag].to_numpy())
                parts.append(
                    pd.DataFrame(
                        {
                            "timestamp": frame["Timestamp"].iloc[index],
                            "tag": tag,
                            "value": frame[tag].to_numpy()[index],
                        }
                    )
                )
            path = Path(tmp) / "export.csv"
            pd.concat(parts).to_csv(path, index=False)
            rows = sum(len(p) for p in parts)
            tags = read_plant_loop(plant_loops(path)[0])
            result = analyze(tags, config=AnalysisConfig(gap=False))
            fit = result.fit
            print(
                f"{name:42s} rows {rows:6d}  samples {tags.n}  {result.verdict.status:12s} "
                f"S {fit.S:.2f} [{fit.S_interval[0]:.2f}, {fit.S_interval[1]:.2f}]  "
                f"J {fit.J:.2f} [{fit.J_interval[0]:.2f}, {fit.J_interval[1]:.2f}]"
            )


if __name__ == "__main__":
    main()
