"""Compare ``stiction analyze`` JSON between this checkout and an earlier revision.

For a change that must not alter results (a refactor, a faster kernel), this runs
``stiction analyze FILE --json`` on every sample loop with the code of both
revisions and lists every field that differs: numbers beyond a relative tolerance,
strings, keys present on one side only.  ``source`` (the path given) and timing
fields are ignored.

    python scripts/compare_analyses.py --base HEAD~3            # sample_data/*.csv
    python scripts/compare_analyses.py --base main --no-gap --rtol 1e-6 FILE ...

The base revision is checked out into a temporary git worktree (removed at the end)
and run with ``PYTHONPATH`` pointing at it, so nothing is installed.  Exit code 0
when every loop matches, 1 when a field differs, 2 on a usage error.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
IGNORED = {"source", "elapsed_s", "timing", "analysed_at", "created"}


def run_analyze(tree: Path, loop: Path, out: Path, extra: list[str]) -> dict:
    """Run the analyze command of the checkout ``tree`` on ``loop``; its JSON."""
    shim = out.parent / f"shim-{tree.name}"
    shim.mkdir(exist_ok=True)
    link = shim / "stiction_cli"
    if not link.exists():
        link.symlink_to(tree / "cli")
    env = dict(os.environ, PYTHONPATH=f"{tree}{os.pathsep}{shim}")
    code = "from stiction_cli.main import main; main()"
    cmd = [sys.executable, "-c", code, "analyze", str(loop), "--json", str(out), *extra]
    done = subprocess.run(cmd, env=env, capture_output=True, text=True, cwd=tree)
    if not out.is_file():
        last = (done.stderr.strip().splitlines() or ["no output"])[-1]
        return {"error": f"exit {done.returncode}: {last}"}
    return json.loads(out.read_text())


def differences(a, b, rtol: float, atol: float, path: str = "") -> list[str]:
    """Fields of two JSON documents that differ, as ``path: a != b`` lines."""
    if isinstance(a, dict) and isinstance(b, dict):
        out = []
        for key in sorted(set(a) | set(b)):
            if key in IGNORED:
                continue
            if key not in a or key not in b:
                side = "base" if key in a else "this checkout"
                out.append(f"{path}.{key}: only in {side}")
                continue
            out += differences(a[key], b[key], rtol, atol, f"{path}.{key}")
        return out
    if isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            return [f"{path}: length {len(a)} != {len(b)}"]
        out = []
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            out += differences(x, y, rtol, atol, f"{path}[{i}]")
        return out
    numbers = (int, float)
    if isinstance(a, numbers) and isinstance(b, numbers) and not isinstance(a, bool):
        if math.isclose(a, b, rel_tol=rtol, abs_tol=atol):
            return []
        return [f"{path}: {a!r} != {b!r}"]
    return [] if a == b else [f"{path}: {a!r} != {b!r}"]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("files", nargs="*", type=Path, help="loops (default sample_data/*.csv)")
    parser.add_argument("--base", required=True, help="git revision to compare with")
    parser.add_argument("--rtol", type=float, default=1e-9, help="relative tolerance")
    parser.add_argument("--atol", type=float, default=1e-12, help="absolute tolerance")
    parser.add_argument("--no-gap", action="store_true", help="skip the gap diagnosis")
    args = parser.parse_args(argv)
    files = [f.resolve() for f in args.files] or sorted((ROOT / "sample_data").glob("*.csv"))
    missing = [str(f) for f in files if not f.is_file()]
    if missing:
        print(f"compare_analyses: no such file: {missing[0]}", file=sys.stderr)
        return 2
    extra = ["--no-gap"] if args.no_gap else []
    with tempfile.TemporaryDirectory(prefix="compare-") as tmp:
        base = Path(tmp) / "base"
        made = subprocess.run(
            ["git", "-C", str(ROOT), "worktree", "add", "--detach", str(base), args.base],
            capture_output=True,
            text=True,
        )
        if made.returncode != 0:
            print(f"compare_analyses: {made.stderr.strip()}", file=sys.stderr)
            return 2
        try:
            n_diff = 0
            for loop in files:
                a = run_analyze(base, loop, Path(tmp) / f"base-{loop.stem}.json", extra)
                b = run_analyze(ROOT, loop, Path(tmp) / f"this-{loop.stem}.json", extra)
                diff = differences(a, b, args.rtol, args.atol)
                n_diff += bool(diff)
                print(f"{loop.name}: {'same' if not diff else f'{len(diff)} fields differ'}")
                for line in diff[:20]:
                    print(f"  {line}")
        finally:
            subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(base)])
    print(f"{len(files) - n_diff} of {len(files)} loops give the same JSON (rtol {args.rtol:g})")
    return 1 if n_diff else 0


if __name__ == "__main__":
    sys.exit(main())
