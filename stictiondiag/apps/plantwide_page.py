"""The fleet page's plant-wide section: groups of loops that share a cycle, their
ranked source candidates, and one spectrum per group (an inline SVG).

It renders the result of the scan's plant-wide step
(:func:`stictiondiag.apps.plantwide.plantwide_step`) and imports nothing of the
scan, so the scan's page writer (:mod:`stictiondiag.apps.scan_output`) uses it
without a circle.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["plant_html"]


def _svg_spectrum(group) -> str:
    """One small SVG: the members' normalised spectra against period (log axis)."""
    from html import escape

    f = group.freq_hz
    keep = f > 0
    period = 1.0 / f[keep]
    x = np.log10(period)
    width, height, pad = 520, 180, 30
    x0, x1 = float(x.min()), float(x.max())
    ymax = float(group.spectra[:, keep].max()) or 1.0
    colours = ("#c0392b", "#2471a3", "#229954", "#b9770e", "#7d3c98", "#566573")

    def px(v):
        return pad + (x1 - v) / max(x1 - x0, 1e-12) * (width - 2 * pad)

    def py(v):
        return height - pad - v / ymax * (height - 2 * pad)

    lines = []
    for i, (m, row) in enumerate(zip(group.members, group.spectra, strict=True)):
        pts = " ".join(f"{px(a):.1f},{py(b):.1f}" for a, b in zip(x, row[keep], strict=True))
        c = colours[i % len(colours)]
        lines.append(f'<polyline fill="none" stroke="{c}" stroke-width="1.2" points="{pts}">'
                     f"<title>{escape(m)}</title></polyline>")  # fmt: skip
        lines.append(
            f'<text x="{width - pad + 4}" y="{pad + 12 * i}" font-size="10" fill="{c}">'
            f"{escape(m)}</text>"
        )
    mark = px(math.log10(group.period_s))
    ticks = "".join(
        f'<text x="{px(math.log10(p)):.1f}" y="{height - 8}" font-size="10" '
        f'text-anchor="middle">{p:g}</text>'
        for p in _ticks(10**x0, 10**x1)
    )
    return (
        f'<svg xmlns="http://www.w3.org/2000/svg" width="{width + 70}" height="{height}">'
        f'<line x1="{mark:.1f}" y1="{pad - 5}" x2="{mark:.1f}" y2="{height - pad}" '
        f'stroke="#999" stroke-dasharray="3,3"/>{"".join(lines)}{ticks}'
        f'<text x="{width / 2}" y="{height}" font-size="10" text-anchor="middle">'
        "period [s] (normalised power spectra of pv)</text></svg>"
    )


def _ticks(lo: float, hi: float) -> list[float]:
    out = []
    for e in range(int(math.floor(math.log10(lo))), int(math.ceil(math.log10(hi))) + 1):
        for m in (1, 2, 5):
            v = m * 10.0**e
            if lo <= v <= hi:
                out.append(v)
    return out


def plant_html(plant: dict | None) -> str:
    """HTML section of the fleet page: the groups, their sources and one plot each."""
    from html import escape

    if not plant:
        return ""
    if plant.get("status") != "on":
        return f'<h2>Plant-wide oscillations</h2><p class="plant-off">{escape(plant["reason"])}</p>'
    diagnosis = plant["diagnosis"]
    if not diagnosis.groups:
        return (
            "<h2>Plant-wide oscillations</h2><p>No oscillation is shared by two loops or more.</p>"
        )
    parts = ["<h2>Plant-wide oscillations</h2>"]
    for g in diagnosis.groups:
        grp = g.group
        rows = "".join(
            f"<tr><td>{k + 1}</td><td>{escape(e.loop)}</td><td>{e.share:.2f}</td>"
            f"<td>{e.lead_s:.0f}</td><td>{_fmt(e.harmonic_ratio)}</td>"
            f"<td>{_fmt(e.probability)}</td>"
            f"<td>{'source candidate' if e.loop in g.candidates else 'propagated'}</td></tr>"
            for k, e in enumerate(g.ranking)
        )
        parts.append(
            f"<h3>Group {grp.group}: period {grp.period_s:.4g} s, {len(grp.members)} loops</h3>"
            f"<p>{escape(g.note)}</p>"
            "<table><thead><tr><th>rank</th><th>loop</th><th>share of power</th>"
            "<th>lead [s]</th><th>harmonics/fundamental</th><th>P(valve)</th>"
            f"<th>role</th></tr></thead><tbody>{rows}</tbody></table>{_svg_spectrum(grp)}"
        )
    return "".join(parts)


def _fmt(v) -> str:
    return "" if v is None or not math.isfinite(float(v)) else f"{float(v):.3g}"
