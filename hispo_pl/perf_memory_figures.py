"""A benchmark's performance against memory (the paper's Figure 2 and a grid's IQM): one point
per method in its own style (:func:`~hispo_pl.figures.method_style`), each named beside its
point where :func:`label_offsets` finds room, on axes whose ticks show the values themselves.

Only ``matplotlib.figure.Figure`` is used (no pyplot), as in :mod:`hispo_pl.figures`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
from matplotlib.figure import Figure
from matplotlib.ticker import ScalarFormatter

from .figures import marker_size, method_style


def plain_ticks(ax) -> None:
    """Tick labels as the values themselves: no offset ("+4") and no scientific notation, so
    equal values never look spread over an axis of 0.00005 steps."""
    for axis in (ax.xaxis, ax.yaxis):
        formatter = ScalarFormatter(useOffset=False)
        formatter.set_scientific(False)
        axis.set_major_formatter(formatter)


def span_limits(lo: float, hi: float, min_span: float) -> tuple[float, float]:
    """Limits around ``[lo, hi]`` at least ``min_span`` wide (centred), with a 10 % margin:
    values that differ in the fifth decimal stay on one spot."""
    centre, half = (lo + hi) / 2, max(hi - lo, min_span) / 2
    return centre - 1.1 * half, centre + 1.1 * half


# Where a label may go around its point, nearest first: rings of growing radius (points on the
# page), eight directions on each. (dx, dy) is a unit direction; the label's box touches the
# point's side of the ring, so a label "east" starts right of the point, "north" sits above it.
LABEL_RADII = (4.0, 12.0, 22.0, 34.0, 48.0, 64.0)
LABEL_DIRECTIONS = ((1, 0), (1, 1), (1, -1), (0, 1), (0, -1), (-1, 0), (-1, 1), (-1, -1))


def label_offsets(
    points: Sequence[tuple[float, float]],
    sizes: Sequence[tuple[float, float]],
    bounds: tuple[float, float, float, float] | None = None,
    marker: float = 7.0,
    obstacles: Sequence[tuple[float, float]] = (),
) -> list[tuple[float, float, bool]]:
    """Where each point's label goes, as the offset in points from the point to the label's
    lower-left corner and whether it needs a leader line: the nearest free place on rings
    around its own point (:data:`LABEL_RADII` × :data:`LABEL_DIRECTIONS`) whose box of
    ``sizes`` (width, height, in points) meets no label already placed and no point's marker
    (``marker`` points wide), inside ``bounds`` (the axes: x0, y0, x1, y1) when given.
    ``points`` are in points on the page. Labels of a crowded spot fan out around it, each
    joined to its point by a leader line, rather than stacking in a column away from it;
    with no free place at all, the label goes right of its point. ``obstacles``: other
    markers (unlabelled, in points on the page) that no label may cover."""
    placed: list[tuple[float, float, float, float]] = []
    offsets = []
    half = marker / 2
    nearby = [*points, *obstacles]  # a label nearer another marker than its own reads as its
    marks = [(px - half, py - half, px + half, py + half) for px, py in nearby]
    for (x, y), (w, h) in zip(points, sizes, strict=True):
        choice = None
        # first a place nearer its own point than any other; in a tight crowd, any free one
        for attached in (True, False):
            for ring, radius in enumerate(LABEL_RADII):
                for ux, uy in LABEL_DIRECTIONS:
                    dx = radius + half if ux > 0 else -radius - half - w if ux < 0 else -w / 2
                    dy = radius + half if uy > 0 else -radius - half - h if uy < 0 else -h / 2
                    if ux and uy:  # a diagonal: the corner of the box on the ring
                        dx, dy = dx - ux * 0.3 * radius, dy - uy * 0.3 * radius
                    box = (x + dx, y + dy, x + dx + w, y + dy + h)
                    free = not any(_overlap(box, o) for o in placed + marks)
                    if free and ring:  # a leader line must not cross a label already placed
                        free = not any(_crosses((x, y), box, o) for o in placed)
                    near = not attached or _nearest((x, y), box, nearby, marker)
                    if free and near and _within(box, bounds):
                        choice = (dx, dy, ring > 0 or not attached)
                        break
                if choice is not None:
                    break
            if choice is not None:
                break
        if choice is None:
            choice = (LABEL_RADII[0] + half, -h / 2, False)
        dx, dy, _ = choice
        placed.append((x + dx, y + dy, x + dx + w, y + dy + h))
        offsets.append(choice)
    return offsets


def _distance(point: tuple[float, float], box: tuple[float, ...]) -> float:
    """From ``point`` to the nearest point of ``box`` (0 inside it)."""
    dx = max(box[0] - point[0], 0.0, point[0] - box[2])
    dy = max(box[1] - point[1], 0.0, point[1] - box[3])
    return float(np.hypot(dx, dy))


def _nearest(own: tuple[float, float], box: tuple[float, ...], points, spot: float) -> bool:
    """Whether no other point (apart from those within ``spot`` of ``own``, whose markers
    touch its own) is nearer to the label's box than its own point: a label read as its
    neighbour's is worse than one a little away."""
    mine = _distance(own, box)
    far = [p for p in points if np.hypot(p[0] - own[0], p[1] - own[1]) > spot]
    return all(_distance(p, box) >= mine for p in far)


def _crosses(own: tuple[float, float], box: tuple[float, ...], other: tuple[float, ...]) -> bool:
    """Whether the leader line from ``own`` to the centre of the label's box passes through
    the box ``other``."""
    cx, cy = (box[0] + box[2]) / 2, (box[1] + box[3]) / 2
    for t in np.linspace(0.0, 1.0, 24):
        px, py = own[0] + t * (cx - own[0]), own[1] + t * (cy - own[1])
        if other[0] < px < other[2] and other[1] < py < other[3]:
            return True
    return False


def _overlap(a: tuple[float, ...], b: tuple[float, ...]) -> bool:
    return a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]


def _within(box: tuple[float, ...], bounds: tuple[float, ...] | None) -> bool:
    if bounds is None:
        return True
    return (
        bounds[0] <= box[0] and bounds[1] <= box[1] and box[2] <= bounds[2] and box[3] <= bounds[3]
    )


def _draw_method(ax, method: str, x: float, y: float, **errors) -> None:
    """One method's point in its own style (:func:`method_style`), with its error bars."""
    style = method_style(method)
    ax.errorbar(x, y, **style, ms=marker_size(style["fmt"]), mec="white", mew=0.6, capsize=3,
                zorder=3, **errors)  # fmt: skip


def _count_note(counts: Mapping[str, int], unit: str, single: str = "") -> str:
    """``3 seeds each`` or ``3 seeds each; 1 seed (no interval): hispo-6k``: what the error
    bars are over, said once instead of in a legend (``single``: said of a count of one)."""
    if not counts:
        return ""

    def many(n: int) -> str:
        return f"{n} {unit}{'s' if n != 1 else ''}{single if n == 1 else ''}"

    usual = max(sorted(set(counts.values())), key=list(counts.values()).count)
    note = f"{many(usual)} each"
    for n in sorted(set(counts.values()) - {usual}):
        note += f"; {many(n)}: {', '.join(m for m, c in counts.items() if c == n)}"
    return note


def perf_vs_memory_figure(rows: Sequence, stream: str = "") -> Figure:
    """The paper's Figure 2: MEM on x, PER (%) on y over the whole 0..100 range, one point per
    method in its own style (rows with ``method``, ``seeds`` and ``metrics``: ``MEM`` and
    ``PER`` as (mean, std)), error bars of the std over seeds where there are several, each
    method named beside its point (no legend); the x label says how many seeds each has."""
    rows = [r for r in rows if "MEM" in r.metrics]
    fig = Figure(figsize=(6.8, 4.5), layout="constrained")
    ax = fig.add_subplot()
    for row in rows:
        (x, xs), (y, ys) = row.metrics["MEM"], row.metrics["PER"]
        several = len(row.seeds) > 1
        _draw_method(ax, row.method, x, 100 * y, xerr=xs if several else None,
                     yerr=100 * ys if several else None)  # fmt: skip
    xs_all = [r.metrics["MEM"][0] for r in rows] or [1.0]
    ax.set_xlim(*span_limits(min(xs_all), max(xs_all), min_span=1.0))
    top = max([100 * sum(r.metrics["PER"]) for r in rows] + [100.0])
    ax.set_ylim(0, top + 4)
    ax.set_yticks(range(0, 101, 20))
    plain_ticks(ax)
    ax.xaxis.set_major_formatter("{x:.2f}")
    note = _count_note({r.method: len(r.seeds) for r in rows}, "seed", " (no interval)")
    ax.set_xlabel("MEM (stored size / one single-task model)" + (f"\n{note}" if note else ""))
    ax.set_ylabel("PER (success %, mean ± std over seeds)")
    ax.set_title(f"Performance vs memory{': ' + stream if stream else ''}")
    ax.grid(alpha=0.3)
    centres = [(r.metrics["MEM"][0], 100 * r.metrics["PER"][0]) for r in rows]
    label_markers(fig, ax, [r.method for r in rows], centres)
    return fig


def label_markers(
    fig: Figure,
    ax,
    names: Sequence[str],
    centres: Sequence[tuple[float, float]],
    fontsize: float = 8,
    obstacles: Sequence[tuple[float, float]] = (),
) -> None:
    """Write each method's name beside its point (data coordinates ``centres``) in its
    colour, where :func:`label_offsets` finds room, clear of the unlabelled markers at
    ``obstacles`` too; a label that had to move past its neighbours keeps a thin leader line
    to its own point."""
    fig.draw_without_rendering()  # the layout's final axes, so labels are placed as drawn
    points = ax.transData.transform(centres) * 72 / fig.dpi if centres else []
    others = ax.transData.transform(obstacles) * 72 / fig.dpi if obstacles else []
    sizes = [(0.62 * fontsize * len(name), 1.2 * fontsize) for name in names]
    frame = ax.get_window_extent().extents * 72 / fig.dpi
    offsets = label_offsets(
        [tuple(p) for p in points],
        sizes,
        bounds=tuple(frame),
        obstacles=[tuple(p) for p in others],
    )
    for name, centre, (dx, dy, leader) in zip(names, centres, offsets, strict=True):
        color = method_style(name)["color"]
        ax.annotate(
            name,
            centre,
            xytext=(dx, dy),
            textcoords="offset points",
            ha="left",
            va="bottom",
            color=color,
            fontsize=fontsize,
            zorder=4,
            arrowprops=dict(arrowstyle="-", color=color, lw=0.6, shrinkA=1, shrinkB=3)
            if leader
            else None,
        )


def iqm_vs_memory_figure(
    rows: Sequence,
    title: str,
    reference: Mapping[str, tuple[float, float]] | None = None,
    reference_name: str = "",
) -> Figure:
    """PER's IQM with its interval against mean MEM, one point per method in its own style
    (rows with ``method``, ``streams``, ``means`` and ``iqm``: point, low, high), each named
    beside its point (no legend); the x label says over how many streams. ``reference``: a
    figure to set beside ours per method, ``(MEM, PER)`` (another protocol's, e.g. a paper's
    on the same streams), drawn hollow in the method's colour and joined to our point by a
    dotted line; ``reference_name`` says whose it is, under the axis."""
    fig = Figure(figsize=(6.4, 4.6), layout="constrained")
    ax = fig.add_subplot()
    drawn = [r for r in rows if "MEM" in r.means]
    for row in drawn:
        point, low, high = row.iqm
        _draw_method(ax, row.method, row.means["MEM"], point,
                     yerr=[[point - low], [high - point]])  # fmt: skip
    reference = reference or {}
    beside = {r.method: reference[r.method] for r in drawn if r.method in reference}
    for row in (r for r in drawn if r.method in beside):
        style, (mem, per) = method_style(row.method), beside[row.method]
        ax.plot([row.means["MEM"], mem], [row.iqm[0], per], ls=":", lw=0.8, color=style["color"])
        ax.plot(mem, per, ls="none", marker=style["fmt"], mfc="none", mec=style["color"],
                ms=marker_size(style["fmt"]), mew=1.2, zorder=3)  # fmt: skip
    xs = [r.means["MEM"] for r in drawn] + [m for m, _ in beside.values()] or [1.0]
    ax.set_xlim(*span_limits(min(xs), max(xs), min_span=1.0))
    ax.set_ylim(0, max([r.iqm[2] for r in drawn] + [100.0]) + 5)  # a bar and a label at 100 %
    ax.set_yticks(range(0, 101, 20))
    plain_ticks(ax)
    ax.xaxis.set_major_formatter("{x:.2f}")
    note = _count_note({r.method: len(r.streams) for r in drawn}, "stream")
    if beside:
        note += f"{'; ' if note else ''}hollow: {reference_name or 'reference'}"
    ax.set_xlabel("MEM (mean stored size / one single-task model)" + (f"\n{note}" if note else ""))
    ax.set_ylabel("PER IQM (success %), 95 % CI")
    ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.3)
    centres = [(r.means["MEM"], r.iqm[0]) for r in drawn]
    label_markers(fig, ax, [r.method for r in drawn], centres, 7, list(beside.values()))
    return fig
