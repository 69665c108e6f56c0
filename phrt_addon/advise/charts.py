"""The advice's pictures (matplotlib Figures on the Agg canvas: no pyplot, no global backend).

- :func:`plot_benefit_per_ms`: one horizontal bar per item, ranked by benefit per ms, tagged and
  untagged items in two colours, each bar labelled with its recommendation;
- :func:`plot_strips`: one strip per item (same order) of its error drop on each judged frame,
  frame on x: where along the path it mattered;
- :func:`write_drop_map`: an item's per-pixel LDR-FLIP drop on one frame as a PNG.
"""
from __future__ import annotations

import numpy as np

TAGGED_COLOUR = "tab:blue"
UNTAGGED_COLOUR = "tab:orange"


def _figure(**kwargs):
    from matplotlib.figure import Figure

    return Figure(**kwargs)


def plot_benefit_per_ms(path, rows, title):
    """``rows``: advice rows (dicts of ``files.advice_rows``) in the order to draw, best at the top."""
    height = max(2.5, 0.32 * len(rows) + 1.4)
    figure = _figure(figsize=(10, height))
    axes = figure.subplots()
    labels = [f"{row['element']} / {row['effect']}" for row in rows]
    values = [max(float(row["benefit_per_ms"]), 0.0) for row in rows]
    colours = [TAGGED_COLOUR if row["tagged"] else UNTAGGED_COLOUR for row in rows]
    positions = np.arange(len(rows))[::-1]
    axes.barh(positions, values, color=colours)
    axes.set_yticks(positions)
    axes.set_yticklabels(labels, fontsize=8)
    top = max(values) if values and max(values) > 0 else 1.0
    for position, value, row in zip(positions, values, rows):
        label = row["recommendation"] if row["tagged"] or row["recommendation"] != "keep" else "leave untagged"
        axes.text(value + 0.01 * top, position, label, va="center", fontsize=7)
    axes.set_xlim(0, top * 1.25)
    axes.set_xlabel("benefit per ms: mean LDR-FLIP removed per ms of tracing (traced alone)")
    axes.set_title(title, fontsize=10)
    from matplotlib.patches import Patch
    axes.legend(handles=[Patch(color=TAGGED_COLOUR, label="tagged"), Patch(color=UNTAGGED_COLOUR,
                                                                           label="untagged (would it be worth it)")],
                loc="lower right", fontsize=8)
    axes.grid(True, axis="x", alpha=0.3)
    figure.tight_layout()
    figure.savefig(path, dpi=100)
    return path


def plot_strips(path, rows, books, judged, title):
    """A heat strip per item: its LDR-FLIP drop on each judged frame (grey: not visible)."""
    judged = sorted(judged)
    grid = np.full((max(len(rows), 1), max(len(judged), 1)), np.nan)
    column = {frame: index for index, frame in enumerate(judged)}
    for line, row in enumerate(rows):
        book = books[row["key"]]
        for frame, value in zip(book.frames, book.benefit):
            grid[line, column[frame]] = max(value, 0.0)
    height = max(2.5, 0.28 * len(rows) + 1.4)
    figure = _figure(figsize=(10, height))
    axes = figure.subplots()
    axes.set_facecolor("#dddddd")
    top = np.nanmax(grid) if np.any(np.isfinite(grid)) and np.nanmax(grid) > 0 else 1.0
    image = axes.imshow(np.ma.masked_invalid(grid), aspect="auto", cmap="viridis", vmin=0.0, vmax=top,
                        interpolation="nearest")
    axes.set_yticks(np.arange(len(rows)))
    axes.set_yticklabels([f"{row['element']} / {row['effect']}" for row in rows], fontsize=8)
    ticks = np.linspace(0, len(judged) - 1, min(len(judged), 10)).round().astype(int) if judged else []
    axes.set_xticks(ticks)
    axes.set_xticklabels([str(judged[t]) for t in ticks], fontsize=8)
    axes.set_xlabel("frame along the path (judged frames; grey: not visible)")
    axes.set_title(title, fontsize=10)
    figure.colorbar(image, ax=axes, label="LDR-FLIP removed when traced alone")
    figure.tight_layout()
    figure.savefig(path, dpi=100)
    return path


def write_drop_map(path, drop):
    """The per-pixel LDR-FLIP drop (raster error minus error with the item traced), red where the
    item removed error, blue where it added some (noise), as a PNG."""
    import matplotlib.image

    drop = np.clip(np.nan_to_num(np.asarray(drop, dtype=np.float64)), -1.0, 1.0)
    scale = max(float(np.max(np.abs(drop))), 1e-6)
    norm = drop / scale
    rgb = np.stack([np.clip(norm, 0, 1), np.zeros_like(norm), np.clip(-norm, 0, 1)], axis=-1)
    matplotlib.image.imsave(str(path), np.round(rgb * 255).astype(np.uint8))
    return path
