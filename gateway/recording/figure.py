"""A :class:`~.plot.Picture` drawn with matplotlib (an optional extra, imported only
here): a panel a row, each legend beside its panel, the marks as labelled vertical
lines, the title; written to a PNG or a PDF, by the name's ending, the title and the
marks in the file's metadata too (so a folder of plotted trials says what each shows)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

from .parquetfile import MissingExtra
from .plot import Picture

if TYPE_CHECKING:
    from matplotlib.figure import Figure

INSTALL_PLOT = "pip install 'gx2-gateway[plot]'"
MARK_COLOUR = "tab:red"
FORMATS = {".png": "Description", ".pdf": "Subject"}
"""What a picture's name may end with (its format), and the metadata key its marks go
under (its title goes under ``Title`` in both)."""


def figure_of(image: Picture) -> Figure:
    """The figure of ``image``: a panel a row, each legend to the right of its panel
    (constrained layout makes room for it), the marks, the title."""
    try:
        import matplotlib
        matplotlib.use("Agg")
        from matplotlib import pyplot
    except ImportError:
        raise MissingExtra(f"plotting needs matplotlib: {INSTALL_PLOT}") from None
    count = max(len(image.panels), 1)
    figure, axes = pyplot.subplots(count, 1, sharex=True, squeeze=False, layout="constrained",
                                   figsize=(12, 2.4 * count + 1.4))
    for axis, panel in zip(axes[:, 0], image.panels, strict=False):
        for label, values in panel.lines.items():
            axis.plot(image.x, values, linewidth=0.8, label=label)
        axis.set_ylabel(f"{panel.title}\n({panel.unit})" if panel.unit else panel.title)
        axis.grid(True, alpha=0.3)
        axis.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0,
                    fontsize="small")
        for at, _ in image.marks:
            axis.axvline(at, color=MARK_COLOUR, linewidth=1.0, linestyle="--")
    top = axes[0, 0]
    middle = (image.x[0] + image.x[-1]) / 2 if image.x else 0.0
    labels = []
    for at, text in image.marks:
        # the label once, at the top panel's top edge (x in data, y in the axes' own
        # 0..1), so it stays put whatever the panel's values; on the line's inner side
        # (left of a mark in the right half), so it does not run past the panel's edge
        right = at <= middle
        label = top.annotate(text, (at, 1.0), xycoords=("data", "axes fraction"),
                             xytext=(2 if right else -2, -2), textcoords="offset points",
                             rotation=90, va="top", ha="left" if right else "right",
                             fontsize="small", color=MARK_COLOUR)
        label.set_in_layout(False)  # (else a long one squashes the panels to make room)
        labels.append(label)
    axes[-1, 0].set_xlabel(image.x_label)
    figure.suptitle(image.title)
    if labels:
        figure.draw_without_rendering()  # the layout (everything else in), whose
        bottom = top.get_window_extent().y0  # panel the labels are fitted into
        _apart(labels, figure.dpi)
        for label in labels:
            _fit(label, bottom)
    return figure


GAP_PX = 1.0
"""Pixels between the labels of marks set side by side."""


def _apart(labels: list[Any], dpi: float) -> None:
    """The labels of marks closer than a label's width set side by side, in the marks'
    order, each moved off its line only as far as the one before it needs (issue 43:
    close marks' labels were drawn over each other). Those right of their line are
    moved right, from the leftmost; those left of it, left, from the rightmost."""
    points = 72 / dpi
    right = sorted((label for label in labels if label.get_ha() == "left"),
                   key=lambda label: label.xy[0])
    left = sorted((label for label in labels if label.get_ha() == "right"),
                  key=lambda label: label.xy[0], reverse=True)
    for side, sign in ((right, 1), (left, -1)):
        edge = None
        for label in side:
            box = label.get_window_extent()
            if edge is not None:
                overlap = edge - box.x0 if sign > 0 else box.x1 - edge
                if overlap > -GAP_PX:
                    x, y = label.xyann
                    label.xyann = (x + sign * (overlap + GAP_PX) * points, y)
                    box = label.get_window_extent()
            edge = box.x1 if sign > 0 else box.x0


ELLIPSIS = "\u2026"


def _fit(label: Any, bottom: float) -> None:
    """Shorten a mark's label (hung from the top panel's top edge) with an ellipsis
    until it ends above ``bottom``, the panel's lower edge (display units)."""
    text = label.get_text()

    def fits(shown: str) -> bool:
        label.set_text(shown)
        return label.get_window_extent().y0 >= bottom

    if fits(text):
        return
    # the longest prefix that fits with the ellipsis: found by halving (fitting is
    # monotone in the prefix's length)
    low, high = 0, len(text)
    while low < high:
        half = (low + high + 1) // 2
        if fits(text[:half].rstrip() + ELLIPSIS):
            low = half
        else:
            high = half - 1
    label.set_text(text[:low].rstrip() + ELLIPSIS)


def unwritable(out: Path) -> str:
    """Why a plot cannot be written to ``out`` (its name's ending); empty if it can."""
    if out.suffix.lower() in FORMATS:
        return ""
    return f"{out}: a plot is written as {' or '.join(FORMATS)} (chosen by the name's ending)"


def draw(image: Picture, out: Path) -> None:
    """Render ``image`` to ``out``, a PNG or a PDF as its name ends (ValueError for
    another ending); the title and the marks go in the file's metadata too, so the
    file says what it shows without being looked at."""
    problem = unwritable(out)
    if problem:
        raise ValueError(problem)
    key = FORMATS[out.suffix.lower()]
    metadata = {"Title": " · ".join(image.title.splitlines())}
    if image.marks:
        metadata[key] = "marks: " + ", ".join(f"{text} at {at:.3f} s"
                                              for at, text in image.marks)
    figure = figure_of(image)
    from matplotlib import pyplot
    try:
        figure.savefig(out, dpi=100, metadata=metadata)
    finally:
        pyplot.close(figure)
