"""The report's lead: per budget, the selection variants side by side, and what differs.

What a reader of a sweep came for, before any long table: at each budget,
each variant's captured share of the oracle's error reduction with its 90%
interval (``captured.py``), its LDR-FLIP, popping, p95 / budget and share of
frames within budget, numbers rounded to what they can mean (a budget in
whole milliseconds, a share to 2 decimals), and a verdict per pair of
variants that names a winner only when the intervals do not overlap, with the
paired difference on the frames both were judged on beside it.
"""
from . import captured
from .markup import ReportTable


def _fixed(value, spec):
    return "–" if value is None else format(value, spec)


def _percent(value):
    return "–" if value is None else f"{100.0 * value:.0f}%"


def captured_text(row) -> str:
    """'0.62 [0.48, 0.75]' (the share with its interval), '–' without an oracle."""
    if row.get("captured") is None:
        return "–"
    if row.get("captured_lo") is None:
        return f"{row['captured']:.2f}"
    return f"{row['captured']:.2f} [{row['captured_lo']:.2f}, {row['captured_hi']:.2f}]"


def _name(row):
    return row.get("variant_name") or row["variant"]


def _as_captured(row) -> captured.Captured:
    return captured.Captured(share=row.get("captured"), low=row.get("captured_lo"), high=row.get("captured_hi"),
                             judged_frames=row.get("judged_frames") or 0)


def verdicts(rows) -> list:
    """One sentence per pair of variants at one budget: who captures more, or 'no difference' (their
    own intervals); with both runs' judged frames (``judged_errors``), the paired difference on the
    frames both have too (``captured.paired_difference``: a difference only when its interval
    leaves out 0)."""
    sentences = []
    for index, first in enumerate(rows):
        for second in rows[index + 1:]:
            verdict = captured.verdict(_name(first), _as_captured(first), _name(second), _as_captured(second))
            sentences.append(f"{_name(first)} against {_name(second)}: {verdict}{_paired(first, second)}")
    return sentences


def _paired(first, second) -> str:
    """'; paired on the same N frames: +0.21 [+0.02, +0.33], benefit captures more' or ''."""
    a, b = first.get("judged_errors"), second.get("judged_errors")
    if not a or not b:
        return ""
    frames = sorted(set(a) & set(b))
    difference, low, high = captured.paired_difference([a[f][0] for f in frames], [a[f][1] for f in frames],
                                                       [b[f][1] for f in frames], [a[f][2] for f in frames])
    if low is None:
        return ""
    said = captured.paired_verdict(_name(first), _name(second), difference, low, high)
    return f"; paired on the same {len(frames)} frames: {difference:+.2f} [{low:+.2f}, {high:+.2f}], {said}"


def by_budget(rows) -> dict:
    """{(scene, path): {budget key: [hybrid rows]}}, budgets in sweep order (budget_at, else ms)."""
    groups = {}
    for row in rows:
        if row["mode"] != "HYBRID":
            continue
        key = row["budget_at"] if row["budget_at"] is not None else row["budget_ms"]
        groups.setdefault((row["scene"], row["path"]), {}).setdefault(key, []).append(row)
    return {group: dict(sorted(budgets.items(), key=lambda item: (item[0] is None, item[0] or 0.0)))
            for group, budgets in groups.items()}


def results_sections(rows) -> list:
    """Report items: per (scene, path) one table of the variants at every budget, then the verdicts."""
    items = []
    for (scene, path), budgets in by_budget(rows).items():
        ends = {row["mode"]: row for row in rows if row["scene"] == scene and row["path"] == path
                and row["mode"] in ("RASTER", "RAYTRACE")}
        table, lines = [], []
        for key, members in budgets.items():
            members = sorted(members, key=lambda row: (_name(row) != "measured", _name(row)))
            for row in members:
                table.append([_fixed(row["budget_at"], ".2f"), _fixed(row["budget_ms"], ".0f"), _name(row),
                              captured_text(row), _fixed(row["flip"], ".3f"), _fixed(row["popping"], ".2f"),
                              _fixed(row["p95_over_budget"], ".2f"), _percent(row.get("within_budget")),
                              _fixed(row["mean_ms"], ".0f"), str(row.get("judged_frames") or "–"),
                              _fixed(row.get("min_regret"), ".3f"), str(row.get("beat_oracle") or 0)])
            if len(members) > 1:
                budget = _fixed(members[0]["budget_ms"], ".0f")
                lines.append(f"at {budget} ms: " + "; ".join(verdicts(members)))
        raster, raytrace = ends.get("RASTER"), ends.get("RAYTRACE")
        intro = ("Per budget, each selection variant: the share of the oracle's error reduction it captures "
                 "(1 = as much as the oracle, 0 = none beyond raster; a ratio of sums over the judged frames, "
                 "with its 90% block-bootstrap interval), its mean LDR-FLIP against the reference, popping per "
                 "100 frames, p95 frame time / budget, the share of frames within budget, the steady mean frame "
                 "time (frames after the first), the judged frames, the lowest regret and the frames where the "
                 "run beat the oracle (benefits measured alone do not add up exactly).")
        if raster is not None and raytrace is not None:
            intro += (f" Raster: LDR-FLIP {_fixed(raster['flip'], '.3f')} at {_fixed(raster['mean_ms'], '.0f')} ms; "
                      f"ray traced (the reference) {_fixed(raytrace['mean_ms'], '.0f')} ms.")
        items.append(("table", ReportTable(
            f"Results: {scene} / {path}",
            ["Budget at", "Budget ms", "Variant", "Captured [90%]", "LDR-FLIP", "Popping / 100", "p95 / budget",
             "Within budget", "Mean ms", "Judged frames", "Min regret", "Beat the oracle"], table, intro)))
        if lines:
            items.append(("p", "Differences between variants (named only where the captured shares' 90% "
                               "intervals do not overlap): " + ". ".join(lines) + "."))
    return items
