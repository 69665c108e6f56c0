"""The advice's files: ``advice.csv``, ``advice.json``, ``advice.md``, ``advice.html`` and two charts.

``advice.csv`` has one row per item (``COLUMNS``, docs/advice.md), then per budget asked
``paper_share_<F>``, ``benefit_share_<F>`` and ``oracle_share_<F>`` (the shares columns are their
means over the budgets).  Rows come worst-value tags first (tagged items by benefit per ms,
lowest first), then the untagged prospects best first.  Every file is written under a temporary
name and renamed.  Plain Python + numpy (+ matplotlib for the charts).
"""
from __future__ import annotations

import csv
import html
import json
import math
import os
from pathlib import Path

import numpy as np

from ..runs import run_log
from . import charts, recommend

COLUMNS = ("element", "effect", "tagged", "visible_share", "mean_pixels", "benefit", "cost_ms", "benefit_per_ms",
           "paper_share", "benefit_share", "oracle_share", "recommendation", "reason")
ADVICE_CSV, ADVICE_JSON, ADVICE_MD, ADVICE_HTML = "advice.csv", "advice.json", "advice.md", "advice.html"
CHART_PNG, STRIPS_PNG = "benefit_per_ms.png", "mattered.png"
MAPS_DIR = "maps"


def plain(value):
    """``value`` as JSON-ready Python: numpy scalars and arrays unwrapped, non-finite floats None,
    floats to 6 significant digits."""
    if isinstance(value, dict):
        return {str(key): plain(item) for key, item in value.items()}
    if isinstance(value, (list, tuple, np.ndarray)):
        return [plain(item) for item in value]
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return float(f"{float(value):.6g}") if math.isfinite(value) else None
    if isinstance(value, Path):
        return str(value)
    return value


def map_name(key: str) -> str:
    """The file of an item's per-pixel drop map inside ``MAPS_DIR``."""
    safe = "".join(character if character.isalnum() or character in "-_." else "_" for character in key)
    return f"{safe}.png"


def advice_rows(books: dict, advice: dict, budgets) -> list:
    """The advice rows in the files' order (worst-value tags first, then untagged best first)."""
    rows = []
    for key, book in books.items():
        row = {"key": key, "element": book.element, "effect": book.effect, "tagged": book.tagged,
               "visible_share": book.visible_share, "mean_pixels": book.mean_pixels, "benefit": book.mean_benefit,
               "cost_ms": book.mean_cost_ms, "benefit_per_ms": book.benefit_per_ms,
               "paper_share": book.share("PAPER"), "benefit_share": book.share("BENEFIT"),
               "oracle_share": book.mean_oracle_share, "recommendation": advice[key].recommendation,
               "reason": advice[key].reason, "frames_measured": len(book.frames)}
        for fraction in budgets:
            for name, column in (("PAPER", "paper_share"), ("BENEFIT", "benefit_share")):
                shares = book.selection_share.get(name)
                row[f"{column}_{fraction:g}"] = shares.get(fraction) if shares else None
            row[f"oracle_share_{fraction:g}"] = book.oracle_share.get(fraction)
        rows.append(row)
    tagged = sorted((row for row in rows if row["tagged"]), key=lambda row: (row["benefit_per_ms"], row["key"]))
    untagged = sorted((row for row in rows if not row["tagged"]), key=lambda row: (-row["benefit_per_ms"], row["key"]))
    return tagged + untagged


def _replace(path: Path, text: str):
    temporary = path.with_name(path.name + ".tmp")
    temporary.write_text(text, encoding="utf-8")
    os.replace(temporary, path)


def write_csv(path, rows, budgets):
    columns = list(COLUMNS) + [f"{column}_{fraction:g}" for fraction in budgets
                               for column in ("paper_share", "benefit_share", "oracle_share")]
    path = Path(path)
    temporary = path.with_name(path.name + ".tmp")
    with open(temporary, "w", newline="", encoding="utf-8") as handle:
        writer = csv.writer(handle, lineterminator="\n")
        writer.writerow(columns)
        for row in rows:
            writer.writerow(["1" if row[column] is True else "0" if row[column] is False
                             else run_log.format_value(row.get(column)) for column in columns])
    os.replace(temporary, path)


def _share(value) -> str:
    return "" if value is None else f"{value:.0%}"


def _table(rows) -> list:
    """Markdown table lines of the rows."""
    lines = ["| item | tagged | visible | pixels | benefit | ms | benefit/ms | PAPER | BENEFIT | oracle | advice |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for row in rows:
        lines.append(f"| {row['element']} / {row['effect']} | {'yes' if row['tagged'] else 'no'} | "
                     f"{row['visible_share']:.0%} | {row['mean_pixels']:.0f} | {row['benefit']:.5f} | "
                     f"{row['cost_ms']:.2f} | {row['benefit_per_ms']:.5f} | {_share(row['paper_share'])} | "
                     f"{_share(row['benefit_share'])} | {row['oracle_share']:.0%} | **{row['recommendation']}** |")
    return lines


def _markdown(info, rows) -> str:
    counts = {name: sum(1 for row in rows if row["recommendation"] == name) for name in recommend.RECOMMENDATIONS}
    prospects = info["prospects"]
    lines = [f"# Tagging advice: {info['scene']} / {info['path']}", "",
             f"Frames {info['frames'][0]}-{info['frames'][1]}, {info['judged_frames']} judged (every "
             f"{info['every']}th), {info['resolution'][0]}x{info['resolution'][1]}; budgets "
             + ", ".join(f"{fraction:g} of the way = {ms:.0f} ms" for fraction, ms in info["budgets_ms"].items())
             + f"; selections replayed: {', '.join(info['selections'])} (the scene's: {info['selection']}).",
             f"Untagged objects judged: {len(prospects['judged'])} (cap {prospects['cap']}, "
             f"{prospects['left_out']} more left out).  Advice took {info['seconds']:.0f} s "
             f"({info['seconds_per_judged_frame']:.1f} s per judged frame).", "",
             "Recommendations: " + ", ".join(f"{name} {count}" for name, count in counts.items() if count), "",
             f"![benefit per ms]({CHART_PNG})", "", f"![where it mattered]({STRIPS_PNG})", "",
             "## Items, worst-value tags first", "", *_table(rows), "", "## Why", ""]
    for row in rows:
        lines.append(f"- **{row['element']} / {row['effect']}: {row['recommendation']}**: {row['reason']}"
                     + (f" ([map]({MAPS_DIR}/{map_name(row['key'])}))" if row.get("map") else ""))
    lines += ["", "benefit = mean LDR-FLIP of the raster frame minus that with the item traced alone, against the "
              "ray traced frame; ms = the median of 3 timings of the trace stage, less its fixed part; shares = "
              "how often each selection / the oracle traced the item on its visible frames (mean over budgets).",
              ""]
    return "\n".join(lines)


def _html(info, rows) -> str:
    head = ("<!doctype html><html><head><meta charset='utf-8'><title>PHRT tagging advice</title><style>"
            "body{font-family:sans-serif;margin:1.5em;max-width:1100px}table{border-collapse:collapse;font-size:13px}"
            "td,th{border:1px solid #ccc;padding:3px 6px;text-align:right}td:first-child,td:last-child{text-align:left}"
            ".untag,.drop_effect{background:#fdd}.tag{background:#ffe4c4}.keep{background:#efe}"
            ".raise_priority,.lower_priority{background:#eef}</style></head><body>")
    body = [f"<h1>Tagging advice: {html.escape(info['scene'])} / {html.escape(info['path'])}</h1>",
            f"<p>{info['judged_frames']} judged frames of {info['frames'][0]}-{info['frames'][1]}; budgets "
            + ", ".join(f"{fraction:g} = {ms:.0f} ms" for fraction, ms in info["budgets_ms"].items())
            + f"; {len(info['prospects']['judged'])} untagged objects judged (cap {info['prospects']['cap']}, "
              f"{info['prospects']['left_out']} left out).</p>",
            f"<img src='{CHART_PNG}' alt='benefit per ms'><br><img src='{STRIPS_PNG}' alt='where it mattered'>",
            "<h2>Items, worst-value tags first</h2><table><tr><th>item</th><th>tagged</th><th>visible</th>"
            "<th>pixels</th><th>benefit</th><th>ms</th><th>benefit/ms</th><th>PAPER</th><th>BENEFIT</th>"
            "<th>oracle</th><th>advice</th><th>why</th></tr>"]
    for row in rows:
        link = f" <a href='{MAPS_DIR}/{map_name(row['key'])}'>map</a>" if row.get("map") else ""
        body.append(
            f"<tr class='{row['recommendation']}'><td>{html.escape(row['element'])} / {row['effect']}</td>"
            f"<td>{'yes' if row['tagged'] else 'no'}</td><td>{row['visible_share']:.0%}</td>"
            f"<td>{row['mean_pixels']:.0f}</td><td>{row['benefit']:.5f}</td><td>{row['cost_ms']:.2f}</td>"
            f"<td>{row['benefit_per_ms']:.5f}</td><td>{_share(row['paper_share'])}</td>"
            f"<td>{_share(row['benefit_share'])}</td><td>{row['oracle_share']:.0%}</td>"
            f"<td><b>{row['recommendation']}</b></td><td>{html.escape(row['reason'])}{link}</td></tr>")
    body.append("</table></body></html>")
    return head + "\n".join(body) + "\n"


def write_advice(out_dir, books, advice, info) -> dict:
    """Write the advice files into ``out_dir``; ``info`` holds the run's facts (scene, path, frames,
    judged_frames, every, resolution, budgets_ms {F: ms}, selections, selection, prospects, seconds,
    seconds_per_judged_frame, maps {key: file}).  Returns {name: path}."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    budgets = list(info["budgets_ms"])
    rows = advice_rows(books, advice, budgets)
    for row in rows:
        row["map"] = info.get("maps", {}).get(row["key"])
    judged = sorted({frame for book in books.values() for frame in book.frames})
    title = f"{info['scene']} / {info['path']}: benefit per ms of each item"
    ranked = sorted(rows, key=lambda row: (-row["benefit_per_ms"], row["key"]))
    charts.plot_benefit_per_ms(out / CHART_PNG, ranked, title)
    charts.plot_strips(out / STRIPS_PNG, ranked, books, judged or info.get("judged", []),
                       f"{info['scene']} / {info['path']}: where along the path each item mattered")
    write_csv(out / ADVICE_CSV, rows, budgets)
    document = {**{key: value for key, value in info.items() if key != "budgets_ms"},
                "budgets_ms": {f"{fraction:g}": ms for fraction, ms in info["budgets_ms"].items()},
                "thresholds": {"noise_flip": recommend.NOISE_FLIP, "priority_gap": recommend.PRIORITY_GAP,
                               "tag_share": recommend.TAG_SHARE},
                "items": [{**{key: value for key, value in row.items() if key != "key"}, "item": row["key"],
                           "frames": books[row["key"]].frames, "benefit_by_frame": books[row["key"]].benefit,
                           "cost_ms_by_frame": books[row["key"]].cost_ms} for row in rows]}
    _replace(out / ADVICE_JSON, json.dumps(plain(document), indent=2, allow_nan=False) + "\n")
    _replace(out / ADVICE_MD, _markdown(info, rows))
    _replace(out / ADVICE_HTML, _html(info, rows))
    return {"csv": out / ADVICE_CSV, "json": out / ADVICE_JSON, "md": out / ADVICE_MD, "html": out / ADVICE_HTML,
            "chart": out / CHART_PNG, "strips": out / STRIPS_PNG}
