"""``stiction validate``: agreement with expert labels on the ISDB's real loops."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Annotated

import typer

from stictiondiag.core.atomic import write_atomic
from stictiondiag.core.errors import UsageError

from .app import app
from .common import check_output_file, friendly_errors, info


def _loop_names(text: str | None) -> list[str] | None:
    """The names of ``--loops`` (comma-separated), None when not given.

    Raises
    ------
    UsageError
        A name that is empty or holds other than letters, digits, ``_`` and ``-``.
    """
    import re

    if text is None:
        return None
    names = [x.strip() for x in text.split(",")]
    bad = [x for x in names if not re.fullmatch(r"[A-Za-z0-9_-]+", x)]
    if bad:
        raise UsageError(f"--loops: not a loop name: {bad[0]!r} (give names like CHEM10,PAP1)")
    return names


@app.command()
def validate(
    isdb: Annotated[
        Path | None,
        typer.Option(
            help="ISDB folder with manifest.csv and loops/ (default ../shared/data/isdb)."
        ),
    ] = None,
    out: Annotated[
        Path | None, typer.Option(help="Write the results page (Markdown) to PATH.")
    ] = None,
    json_path: Annotated[
        str | None,
        typer.Option("--json", help="Write per-loop table and scores as JSON ('-' = stdout)."),
    ] = None,
    workers: Annotated[int | None, typer.Option(min=1, help="Worker processes.")] = None,
    gap: Annotated[bool, typer.Option(help="Include the gap diagnosis per loop.")] = True,
    loops: Annotated[
        str | None, typer.Option(help="Only these loops (comma-separated names).")
    ] = None,
    expert_causes: Annotated[
        bool,
        typer.Option(
            help="Only the loops whose comment names a cause (quantisation, external "
            "disturbance, tuning, dead zone): the gap's cause against the expert's."
        ),
    ] = False,
) -> None:
    """Analyse every ISDB loop; compare verdicts (and baselines) with the published labels."""
    from stictiondiag.apps.validation import (
        render_markdown,
        validate_isdb,
    )

    with friendly_errors():
        check_output_file("--out", out)
        check_output_file("--json", json_path)

        def progress(i: int, n: int, loop: str) -> None:
            info(f"[{i}/{n}] {loop}")

        chosen = _loop_names(loops)
        if expert_causes:
            from stictiondiag.apps.validation import catalogue_cause, load_manifest

            m = load_manifest(isdb)
            named = [
                str(r.loop)
                for r in m.itertuples()
                if catalogue_cause(r.other_fault_published)[0] is not None
            ]
            chosen = [x for x in named if chosen is None or x in chosen]
        if chosen is not None:
            from stictiondiag.apps.validation import load_manifest as _manifest

            unknown = sorted(set(chosen) - set(_manifest(isdb)["loop"].astype(str)))
            if unknown:
                raise UsageError(f"--loops: not in the ISDB manifest: {', '.join(unknown)}")
        result = validate_isdb(isdb, workers=workers, gap=gap, loops=chosen, progress=progress)
        cmd = (
            "stiction validate"
            + (f" --isdb {isdb}" if isdb else "")
            + (f" --loops {loops}" if loops else "")
            + (" --expert-causes" if expert_causes else "")
            + (f" --out {out}" if out else "")
            + ("" if gap else " --no-gap")
        )
        md = render_markdown(result, command=cmd)
        if out:
            write_atomic(out, md)
            info(f"wrote {out}")
        payload = {
            "scores": result.scores,
            "loops": json.loads(result.table.to_json(orient="records")),
        }
        if json_path == "-":
            sys.stdout.write(json.dumps(payload, indent=1) + "\n")
        elif json_path:
            write_atomic(json_path, json.dumps(payload, indent=1) + "\n")
        if result.causes:
            typer.echo(
                f"gap names the expert's cause: {result.causes['agree']} of "
                f"{result.causes['n']} loops"
            )
        s = result.scores["ours"]["stated"]
        typer.echo(
            f"stated labels: n={s['n']} accuracy={s['accuracy']:.2f} "
            f"false positives={s['fp']} missed={s['fn']} inconclusive={s['inconclusive']}"
            if s["accuracy"] is not None
            else "no stated labels",
            err=json_path == "-",
        )
