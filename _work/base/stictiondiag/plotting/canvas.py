"""Cheap figure building and PNG saving, shared by the plot modules.

Drawing text is what a figure of ours costs (matplotlib lays out and renders every
tick label glyph by glyph), so the plots avoid anything that draws a figure twice:

* :func:`new_figure` makes a figure outside pyplot's global registry (nothing to
  leak when a caller forgets ``plt.close``, nothing shared between threads) on a
  canvas that writes PNGs with zlib level :data:`PNG_COMPRESS_LEVEL` (lossless:
  the same pixels, a few % more bytes, written about twice as fast as level 6);
* :func:`place_axes` sets the margins and gaps in inches, estimated from the text
  that needs the room (:func:`text_width`, :func:`ytick_room`), instead of
  ``tight_layout``, which lays out every label once more, and at the next
  ``savefig`` makes matplotlib draw the figure twice;
* :func:`decimate` reduces a long time trend to the min and max of each pixel
  column or so, which draws the same picture (spikes and jumps included).
"""

from __future__ import annotations

import functools
from typing import Literal

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.font_manager import FontProperties, findfont
from matplotlib.ft2font import FT2Font, LoadFlags
from matplotlib.text import Text

#: zlib level of saved PNGs (PIL's default is 6).
PNG_COMPRESS_LEVEL = 1
#: Trends longer than this are decimated; :data:`DECIMATE_POINTS` points are kept.
DECIMATE_ABOVE, DECIMATE_POINTS = 4000, 2000


class FastPngCanvas(FigureCanvasAgg):
    """Agg canvas whose PNGs default to zlib level :data:`PNG_COMPRESS_LEVEL`.

    ``savefig(..., pil_kwargs={"compress_level": 9})`` still overrides it.
    """

    def print_png(self, filename_or_obj, *, metadata=None, pil_kwargs=None, **_ignored):
        # savefig passes dpi, facecolor, ... too; Agg's print_png takes them from the
        # figure (matplotlib drops them for its own canvases, not for subclasses).
        pil_kwargs = {"compress_level": PNG_COMPRESS_LEVEL, **(pil_kwargs or {})}
        return super().print_png(filename_or_obj, metadata=metadata, pil_kwargs=pil_kwargs)


def new_figure(nrows: int, ncols: int, figsize, width_ratios=None) -> tuple[Figure, np.ndarray]:
    """A figure on a :class:`FastPngCanvas` and its ``nrows x ncols`` array of axes.

    The figure is not registered with pyplot; ``plt.close(fig)`` is harmless.
    """
    fig = Figure(figsize=figsize)
    FastPngCanvas(fig)
    gridspec_kw = {"width_ratios": width_ratios} if width_ratios is not None else None
    axes = fig.subplots(nrows, ncols, squeeze=False, gridspec_kw=gridspec_kw)
    return fig, axes


def place_axes(
    fig: Figure,
    *,
    left: float,
    right: float,
    top: float,
    bottom: float,
    wspace: float,
    hspace: float,
) -> None:
    """Margins and gaps between the axes of the figure's grid, in inches."""
    w, h = fig.get_size_inches()
    spec = fig.axes[0].get_subplotspec()
    assert spec is not None, "place_axes needs axes on a grid (new_figure)"
    nrows, ncols = spec.get_gridspec().get_geometry()
    cell_w = (w - left - right - (ncols - 1) * wspace) / ncols  # mean axes width
    cell_h = (h - top - bottom - (nrows - 1) * hspace) / nrows
    fig.subplots_adjust(
        left=left / w,
        right=1 - right / w,
        top=1 - top / h,
        bottom=bottom / h,
        wspace=wspace / cell_w if ncols > 1 else 0.2,
        hspace=hspace / cell_h if nrows > 1 else 0.2,
    )


@functools.lru_cache(maxsize=16)
def _advances(fname: str) -> tuple[dict, float]:
    """Advance widths [em] of the printable ASCII characters (and the minus sign)."""
    font = FT2Font(fname)
    font.set_size(72, 72)  # one em = 72 px
    chars = [chr(c) for c in range(32, 127)] + ["\N{MINUS SIGN}"]
    adv = {}
    for c in chars:
        glyph = font.load_char(ord(c), flags=LoadFlags.NO_HINTING)
        adv[c] = glyph.linearHoriAdvance / 65536 / 72
    return adv, max(adv.values())


def text_width(text: str, size=None, family=None) -> float:
    """Width [in] of ``text`` (its longest line) in the font matplotlib would pick.

    An estimate from the characters' advance widths (no kerning, no hinting): within
    a few % of the drawn width.
    """
    prop = FontProperties(family=family, size=size)
    adv, widest = _advances(findfont(prop))
    em = prop.get_size_in_points() / 72
    return max(sum(adv.get(c, widest) for c in line) for line in str(text).split("\n")) * em


def _tick_labels(axis) -> list[str]:
    """The major tick labels the axis will draw at its current limits and size."""
    lo, hi = sorted(axis.get_view_interval())
    tol = 1e-9 * max(abs(hi - lo), 1e-300)
    locs = [v for v in axis.get_major_locator()() if lo - tol <= v <= hi + tol]
    return [s for s in axis.get_major_formatter().format_ticks(locs) if s]


def _tick_text_room(axis, labels: list[str]) -> float:
    """Room [pt] from the spine to the far side of the tick labels (tick, pad, text)."""
    tick = axis.majorTicks[0]
    room = tick.get_tick_padding() + tick.get_pad()
    if not tick.label1.get_visible() or not labels:
        return room
    size = tick.label1.get_fontsize()
    if axis.axis_name == "y":
        return room + max(text_width(s, size) for s in labels) * 72
    lines = max(s.count("\n") + 1 for s in labels)
    # Height of matplotlib's text box: one em, 1.2 em a further line, the descent.
    return room + size * (1 + 1.2 * (lines - 1) + (0.24 if lines > 1 else 0))


def ytick_room(ax) -> float:
    """Room [in] left of ``ax`` taken by its y tick labels and y label."""
    axis = ax.yaxis
    room = _tick_text_room(axis, _tick_labels(axis))
    label = axis.label
    if label.get_text():
        room += axis.labelpad + label.get_fontsize() * (1 + 1.2 * label.get_text().count("\n"))
    return room / 72


def pin_decorations(fig: Figure) -> None:
    """Fix the axis labels and titles where matplotlib would put them, so that a
    draw does not place them again (which recomputes every tick of the axes).

    Call it last, once the axes have their data, limits and final place.  The
    x (y) label goes below (left of) the tick labels, their width estimated with
    :func:`text_width`; a title stays where matplotlib would put it unless a y
    offset text (as ``1e-7``) may push it up.  Axes with a fixed aspect ratio (their
    limits change at the draw) keep matplotlib's placement.
    """
    for ax in fig.axes:
        if not ax.axison:
            continue
        auto = ax.get_aspect() != "auto"
        box = ax.get_position()  # figure fraction, after subplots_adjust
        w_pt = box.width * fig.get_figwidth() * 72
        h_pt = box.height * fig.get_figheight() * 72
        for axis, size_pt in ((ax.xaxis, h_pt), (ax.yaxis, w_pt)):
            name = axis.axis_name
            label = axis.label
            if not label.get_text():
                # Nothing drawn: only skip the placement.
                axis.set_label_coords(*((0.5, 0.0) if name == "x" else (0.0, 0.5)))
                continue
            default_side = "bottom" if name == "x" else "left"
            if auto or axis.get_label_position() != default_side:
                continue
            labels = _tick_labels(axis)
            if name == "x" and axis.get_ticks_position() not in ("bottom", "default"):
                continue
            if name == "y" and axis.get_ticks_position() not in ("left", "default"):
                continue
            offset = (_tick_text_room(axis, labels) + axis.labelpad) / size_pt
            axis.set_label_coords(*((0.5, -offset) if name == "x" else (-offset, 0.5)))
        if auto or ax.xaxis.get_ticks_position() not in ("bottom", "default"):
            continue
        # The left and right titles have no public accessor; without them, leave
        # the titles to matplotlib.
        left, right = getattr(ax, "_left_title", None), getattr(ax, "_right_title", None)
        if left is None or right is None:
            continue
        titles: dict[Literal["left", "center", "right"], Text] = {
            "left": left,
            "center": ax.title,
            "right": right,
        }
        if not any(t.get_text() for t in titles.values()):
            continue
        _tick_labels(ax.yaxis)
        if ax.yaxis.get_major_formatter().get_offset():
            continue
        for loc, t in titles.items():
            if t.get_text():
                # y=1.0 is matplotlib's place here; given, it is not recomputed.
                # (Copies: set_title first resets the title's own properties.)
                ax.set_title(
                    t.get_text(),
                    loc=loc,
                    y=1.0,
                    fontproperties=t.get_fontproperties().copy(),
                    color=t.get_color(),
                )


def decimate(x, y, n_out: int = DECIMATE_POINTS, above: int = DECIMATE_ABOVE):
    """``(x, y)`` reduced to the first and last point and the min and max of ``y``
    over each of ``n_out / 2`` equal runs of samples, in sample order.

    Drawn as a line over a few hundred pixels this is the same picture as the whole
    series: every spike, step and slip jump keeps its extremes.  Series of at most
    ``above`` points, and series with NaN (gaps), are returned as they are.
    """
    x, y = np.asarray(x), np.asarray(y)
    n = y.size
    if n <= above or x.size != n or not np.all(np.isfinite(y)):
        return x, y
    runs = max(1, n_out // 2)
    k = -(-n // runs)  # samples per run
    padded = np.empty(runs * k, dtype=y.dtype)
    padded[:n] = y
    padded[n:] = y[-1]
    blocks = padded.reshape(runs, k)
    base = np.arange(runs) * k
    i_min = base + np.argmin(blocks, axis=1)
    i_max = base + np.argmax(blocks, axis=1)
    keep = np.concatenate(([0], np.minimum(i_min, n - 1), np.minimum(i_max, n - 1), [n - 1]))
    keep = np.unique(keep)
    return x[keep], y[keep]
