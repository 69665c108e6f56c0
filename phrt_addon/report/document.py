"""The report document's sections (items for ``markup``): Table II beside the paper's, runs, errors,
stability, and with a sweep the runs on the error-time curve, regret, popping and the relevance verdict.
"""
import numpy as np

from .. import defaults
from . import captured, metrics, oracle
from .markup import ReportTable
from .results import results_sections
from .runs import BASELINE_VARIANT, PAPER_SCENES, PAPER_TABLE_II, WORST_ELEMENTS
from .selection import RunRegret, variant_label


def _ms(value):
    return "–" if value is None else f"{value:.1f}"


def _number(value, spec):
    return "–" if value is None else format(value, spec)


def table_ii_hybrid(members):
    """The hybrid run a Table II row shows: the paper's heuristic (baseline variant) at the budget
    nearest the sample scenes' Budget At, else the first hybrid run."""
    hybrids = [run for run in members if run.mode == "HYBRID"]
    if not hybrids:
        return None
    baseline = [run for run in hybrids if run.variant == BASELINE_VARIANT] or hybrids
    return min(baseline, key=lambda run: abs((run.budget_at if run.budget_at is not None
                                              else defaults.BUDGET_AT) - defaults.BUDGET_AT))


def _ratio(numerator, denominator):
    return None if numerator is None or not denominator else numerator / denominator


def table_ii_rows(groups):
    """Rows of the Table II section: scene, path, raster / hybrid / ray tracing ms, our ratios beside
    the paper's, and the hybrid run shown."""
    rows = []
    for (scene, path), members in groups.items():
        means = {}
        for mode in ("RASTER", "RAYTRACE"):
            runs = [run for run in members if run.mode == mode]
            means[mode] = runs[0].steady("mean") if runs else None
        hybrid = table_ii_hybrid(members)
        means["HYBRID"] = hybrid.steady("mean") if hybrid is not None else None
        paper = PAPER_TABLE_II.get((PAPER_SCENES.get(scene, scene), path))
        rows.append([scene, path, _ms(means["RASTER"]), _ms(means["HYBRID"]), _ms(means["RAYTRACE"]),
                     _number(_ratio(means["HYBRID"], means["RASTER"]), ".2f"),
                     _number(_ratio(paper[1], paper[0]) if paper else None, ".2f"),
                     _number(_ratio(means["RAYTRACE"], means["HYBRID"]), ".2f"),
                     _number(_ratio(paper[2], paper[1]) if paper else None, ".2f"),
                     hybrid.label if hybrid is not None else "–"])
    return rows


def report_sections(runs, groups, references, errors, files, rows=None, regrets=None, pops=None, oracle_results=None):
    """The report as a list of items: ('h', text), ('p', text), ('table', ReportTable), ('img', file)."""
    rows = rows or []
    regrets = regrets or {}
    pops = pops or {}
    items = [("h1", "PHRT report")]
    items.append(("p", f"{len(runs)} runs of {len(groups)} camera path(s). Frame times are steady: over the "
                       f"frames after each run's first, one-time work out (the first frame's own cost is in the "
                       f"Runs table); milliseconds per frame."))
    items.append(("img", files.error_vs_time_png.name,
                  "Mean LDR-FLIP (left) and relMSE (right) against steady mean frame time: each selection "
                  "variant's runs joined from raster through its budgets to ray tracing, the Pareto front dashed, "
                  "each hybrid point's budget marked (a tick dotted to the point, and a red line per budget)."))
    partial = [run for run in runs if run.summary.get("partial")]
    if partial:
        items.append(("p", "Partial runs (stopped, killed or failed before their last frame; the report uses the "
                           "frames their summary.json commits): " + "; ".join(
                               f"{run.label} ({len(run.frames)} of {run.summary.get('frames_planned', '?')} frames"
                               f"{': ' + str(run.summary['error']) if run.summary.get('error') else ''})"
                               for run in partial) + "."))
    items += results_sections(rows)

    items.append(("table", ReportTable(
        "Render times (ms per frame), after the paper's Table II",
        ["Scene", "Path", "Raster rendering", "Hybrid rendering", "Ray tracing rendering", "Hybrid / raster",
         "Paper: hybrid / raster", "Ray tracing / hybrid", "Paper: ray tracing / hybrid", "Hybrid run"],
        table_ii_rows(groups),
        "Steady mean time to render a frame of the path in each mode, laid out like the paper's Table II, "
        "with our ratios beside the paper's own (its Table II: 640x480, 1000 frames per path, a GTX 460M); "
        "milliseconds on different machines do not compare, ratios may. The arcade scene stands for the "
        "paper's Sponza, atrium for its atrium. The hybrid column is the paper's heuristic (measured "
        f"cost, I = {defaults.SELECTION_WEIGHT:g}, R order, paper relevance) at the budget nearest "
        f"{defaults.BUDGET_AT:g} of the way from raster to ray traced time, or the only hybrid run.")))

    items += _sweep_sections(rows, groups, regrets, pops, oracle_results, files)

    run_rows = []
    for run in runs:
        budget = run.summary.get("budget_ms")
        within = run.within_budget() if run.mode == "HYBRID" else None
        run_rows.append([
            run.label, f"{run.scene} / {run.path}", run.mode.lower(),
            _number(budget, ".0f"), str(len(run.frames)) + (" (partial)" if run.summary.get("partial") else ""), _ms(run.first_frame_ms), _ms(run.steady("mean")),
            _ms(run.steady("p50")), _ms(run.steady("p95")), _ms(run.steady("max")),
            _ms(run.mean("raster_ms")), _ms(run.mean("select_ms")), _ms(run.mean("trace_ms")),
            _ms(run.mean("composite_ms")), _number(run.mean("n_selected"), ".1f"),
            "–" if within is None else f"{100.0 * within:.0f}%"])
    items.append(("table", ReportTable(
        "Runs",
        ["Run", "Scene / path", "Mode", "Budget ms", "Frames", "First frame ms", "Mean ms", "p50 ms", "p95 ms",
         "Max ms", "Raster ms", "Select ms", "Trace ms", "Composite ms", "Mean selected",
         "Within budget"], run_rows,
        "Frame time statistics are steady (the frames after the first, one-time work out); the first "
        "frame's own time beside them. Stage columns are means per frame; 'within budget' is the share of "
        "steady hybrid frames whose time met the budget.")))

    error_rows = []
    for run in runs:
        outcome = errors[id(run)]
        reference = references[run.group]
        error_rows.append([
            run.label, f"{run.scene} / {run.path}", run.mode.lower(),
            reference.label if reference else "–",
            str(len(outcome.per_frame)) if run is not reference else str(len(run.frames)),
            _number(outcome.mean("flip"), ".4f"), _number(outcome.mean("relmse"), ".3g"),
            _number(outcome.mean("psnr_db"), ".2f"), outcome.note])
    items.append(("table", ReportTable(
        "Error against the reference",
        ["Run", "Scene / path", "Mode", "Reference", "Frames compared", "Mean LDR-FLIP",
         "relMSE", "PSNR dB", "Note"], error_rows,
        f"Frames are matched by frame number; every image is tone-mapped the same way "
        f"(clamp to [0, 1], sRGB encoding: Blender's 'Standard' view transform) before "
        f"LDR-FLIP (67 pixels per degree) and PSNR; relMSE = mean((x - y)^2 / (y^2 + "
        f"{metrics.RELMSE_EPSILON:g})) on linear HDR values. Values are means over the "
        f"compared frames, except PSNR: the PSNR of the mean per-frame MSE (a frame identical "
        f"to the reference would otherwise count at the {metrics.PSNR_CAP_DB:g} dB cap). "
        f"Per-frame values: [{files.errors_csv.name}]({files.errors_csv.name}).")))
    items.append(("img", files.timeline_png.name,
                  "Frame time of each run per frame with the budget (dashed), and selected elements."))

    stability_rows = []
    for run in runs:
        rates = run.selection.flips_per_element_per_100()
        worst = sorted(((rate, element) for element, rate in rates.items() if rate > 0),
                       key=lambda item: (-item[0], item[1]))[:WORST_ELEMENTS]
        values = np.array(list(rates.values()), dtype=float)
        stability_rows.append([
            run.label, run.mode.lower(), str(len(rates)),
            _number(float(values.mean()) if values.size else None, ".2f"),
            _number(float(values.max()) if values.size else None, ".2f"),
            ", ".join(f"{element} ({rate:.2f})" for rate, element in worst) or "none"])
    items.append(("table", ReportTable(
        "Selection stability",
        ["Run", "Mode", "Elements", "Mean flips / element / 100 frames", "Max",
         "Worst elements"], stability_rows,
        "A flip is an element switching between raster and ray tracing from one frame to "
        "the next; the paper asks that no element changes repeatedly.")))

    machine_rows = []
    for key, title in (("blender_version", "Blender"), ("embreex_version", "embreex")):
        machine_rows.append([title, ", ".join(sorted({str(run.summary.get(key)) for run in runs}))])
    for key, title in (("cpu_model", "CPU"), ("cores", "Cores")):
        machine_rows.append([title, ", ".join(sorted(
            {str((run.summary.get("machine") or {}).get(key)) for run in runs}))])
    items.append(("table", ReportTable("Machine and versions", ["", ""], machine_rows)))
    return items


def _signed(value, spec):
    return "–" if value is None else format(value, "+" + spec)


def _top(counts, limit=WORST_ELEMENTS):
    ranked = sorted(counts.items(), key=lambda item: (-item[1], item[0]))[:limit]
    return ", ".join(f"{name} ({count})" for name, count in ranked) or "none"


SWEEP_TABLE_TITLE = "Runs on the error-time curve"


# How the sweep table shows each column of sweep.csv (the test of their agreement reads this).
SWEEP_TABLE_FORMATS = (("run", "Run", None), ("mode", "Mode", None), ("variant", "Selection", None),
                       ("budget_at", "Budget at", ".2f"), ("budget_ms", "Budget ms", ".1f"),
                       ("mean_ms", "Mean ms", ".1f"), ("p95_ms", "p95 ms", ".1f"), ("flip", "LDR-FLIP", ".4f"),
                       ("relmse", "relMSE", ".4g"), ("psnr", "PSNR dB", ".2f"), ("regret", "Regret", ".4f"),
                       ("regret_share", "Regret share", ".2f"),
                       ("flips_per_100", "Flips / element / 100 frames", ".2f"),
                       ("popping", "Popping / 100 frames", ".4f"), ("mean_selected", "Mean selected", ".1f"))


def _sweep_sections(rows, groups, regrets, pops, oracle_results, files):
    items = []
    items.append(("table", ReportTable(
        SWEEP_TABLE_TITLE, [title for _, title, _ in SWEEP_TABLE_FORMATS],
        [[(_number(row[key], spec) if spec else str(row[key])) if row[key] is not None else "–"
          for key, _, spec in SWEEP_TABLE_FORMATS] for row in rows],
        f"One row per run, the numbers of [{files.sweep_csv.name}]({files.sweep_csv.name}) and "
        f"[{files.sweep_json.name}]({files.sweep_json.name}). Selection: the relevance (the paper's R or the "
        "error-aware one), the cost model, the selection weight I and the greedy order (the paper's R order "
        "unless 'R/ms order'). Budget at: the fraction of the way from raster to ray traced frame time the "
        "budget was resolved from. Regret: mean over the oracle's sampled frames; regret share: the regret as a share "
        "of what the oracle gains over raster (see Regret against the oracle). Popping: summed "
        "popping of all flips per 100 frames (see Popping).")))

    by_budget = {}
    for row in rows:
        if row["mode"] == "HYBRID" and row["budget_at"] is not None:
            by_budget.setdefault((row["scene"], row["path"]), {}).setdefault(row["variant"], {})[
                row["budget_at"]] = row
    for (scene, path), variants in by_budget.items():
        fractions = sorted({fraction for per_budget in variants.values() for fraction in per_budget})
        if len(variants) > 1:
            items.append(("table", ReportTable(
                f"Selection knobs: {scene} / {path}",
                ["Selection"] + [f"at {fraction:.2f}: LDR-FLIP / regret" for fraction in fractions],
                [[variant] + [(f"{_number(per_budget[f]['flip'], '.4f')} / {_number(per_budget[f]['regret'], '.4f')}"
                               if f in per_budget else "–") for f in fractions]
                 for variant, per_budget in sorted(variants.items(), key=lambda item: (
                     item[0] != variant_label(BASELINE_VARIANT), item[0]))],
                "Which part of the selection loses the error: each row changes one knob of the paper's "
                "heuristic (the cost model, the selection weight I, the greedy order, the relevance); "
                "columns are the budgets of the sweep.")))
        paper_label = variant_label(BASELINE_VARIANT)
        error_label = variant_label(BASELINE_VARIANT[:3] + ("error", "paper"))
        if paper_label in variants and error_label in variants:
            items += _relevance_comparison(scene, path, variants[paper_label], variants[error_label])

    hybrid_rows = [row for row in rows if row["mode"] == "HYBRID"]
    if hybrid_rows:
        regret_table = []
        for run, row in ((run, row) for group in groups.values() for run in group
                         for row in rows if row["run"] == run.label and run.mode == "HYBRID"):
            regret = regrets.get(id(run)) or RunRegret(note="not measured")
            regret_table.append([
                run.label, row["variant"], _number(row["budget_ms"], ".1f"), str(regret.frames),
                _number(regret.heuristic_flip, ".4f"), _number(regret.oracle_flip, ".4f"),
                _number(regret.mean, ".4f"), _number(regret.max, ".4f"),
                _number(None if regret.lost_share is None else 100.0 * regret.lost_share, ".0f"), str(regret.differs),
                str(regret.overran), _top(regret.oracle_only), _top(regret.heuristic_only), regret.note])
        every = oracle_results.info.get("every") if oracle_results is not None else oracle.DEFAULT_EVERY
        link = (f" Per frame: [{oracle.REGRET_CSV}]({oracle.REGRET_CSV}); each candidate's measured benefit "
                f"and cost: [{oracle.CANDIDATES_CSV}]({oracle.CANDIDATES_CSV})." if oracle_results is not None else "")
        capped = (oracle_results.info.get("capped") or {}) if oracle_results is not None else {}
        if capped:
            judged = sum(pair[0] for pair in capped.values())
            total = sum(pair[1] for pair in capped.values())
            link += (f" The oracle was capped on {len(capped)} sampled frame(s): it judged {judged} of their {total} "
                     f"candidates (the most relevant by the selection's own estimate plus a few at random), so "
                     f"its choice there is among those only.")
        items.append(("table", ReportTable(
            "Regret against the oracle",
            ["Run", "Selection", "Budget ms", "Sampled frames", "Heuristic LDR-FLIP", "Oracle LDR-FLIP",
             "Mean regret", "Max regret", "Lost %", "Frames the oracle chose otherwise", "Frames over T",
             "Oracle chose, heuristic did not (frames)", "Heuristic chose, oracle did not (frames)", "Note"],
            regret_table,
            f"Computed after the runs, outside every timed region. On every {every}th frame each visible "
            "candidate is rendered traced alone: its benefit is the drop of the frame's LDR-FLIP against the "
            "reference from the raster frame, its cost the trace stage's measured ms. The oracle takes the "
            "subset with the most benefit whose cost fits the heuristic's time left T in that frame (or, "
            "when the heuristic overran T, what its own choice cost: 'frames over T'), an exact knapsack "
            "(branch and bound), renders it and measures it: regret = LDR-FLIP(heuristic) - LDR-FLIP(oracle). "
            "Lost %: the regret as a share of what the oracle gains over raster, averaged over the sampled "
            "frames where it gains anything (a frame with no time left has nothing to lose). "
            "Benefits only roughly add up (a reflection may show another traced element), so a regret "
            "slightly below 0 is possible." + link)))

    pop_rows = []
    for group in groups.values():
        for run in group:
            pop = pops.get(id(run))
            if pop is None:
                continue
            per_element = pop.per_element()
            worst = sorted(per_element.items(), key=lambda item: (-item[1][1], item[0]))[:WORST_ELEMENTS]
            rates = np.array(list(run.selection.flips_per_element_per_100().values()), dtype=float)
            pop_rows.append([
                run.label, run.mode.lower(), str(len(pop.pops)),
                _number(float(rates.mean()) if rates.size else None, ".2f"),
                _number(pop.per_100_frames(), ".4f"),
                _number(float(np.mean([p.popping for p in pop.pops])) if pop.pops and pop.measured else None, ".4f"),
                ", ".join(f"{name} ({flips} flips, {total:+.3f})" for name, (flips, total) in worst
                          if pop.measured) or "none",
                pop.note or ("reference" if run.mode == "RAYTRACE" and not pop.pops else "")])
    if pop_rows:
        items.append(("table", ReportTable(
            "Popping",
            ["Run", "Mode", "Flips", "Flips / element / 100 frames", "Popping / 100 frames", "Mean per flip",
             "Worst elements (flips, summed popping)", "Note"], pop_rows,
            "For each element whose traced state flipped between consecutive frames: LDR-FLIP between the "
            "two frames inside the element's pixels (either frame's), minus the same in the reference run. "
            "About 0: the switch does not show beyond the camera's motion (an element entering or leaving "
            "the view flips too, and pops as much as the reference changes); positive: a visible pop. "
            "Popping / 100 frames sums every flip's popping per 100 frames of the run.")))
    if files.selection_quality_png is not None:
        items.append(("img", files.selection_quality_png.name,
                      "Mean regret against the oracle (left) and popping per 100 frames (right) against the "
                      "frame budget, one curve per selection variant."))
    return items


def relevance_verdict(paper, error):
    """The paper's relevance against the error-aware one over the budgets both ran ({budget_at: sweep
    row}): at each budget a difference only where the captured shares' 90% intervals do not overlap
    ("no difference" otherwise), then the mean LDR-FLIP over those budgets and the budgets where each
    is lower, as numbers.  Returns (text, relative change of the mean LDR-FLIP or None)."""
    shared = sorted(fraction for fraction in set(paper) & set(error)
                    if paper[fraction]["flip"] is not None and error[fraction]["flip"] is not None)
    if not shared:
        return "the two relevances could not be compared (no error measured).", None
    said = {"error-aware": 0, "paper": 0, captured.NO_DIFFERENCE: 0}
    for fraction in shared:
        verdict = captured.verdict("error-aware", _judged(error[fraction]), "paper", _judged(paper[fraction]))
        said[verdict.replace(" captures more", "")] += 1
    if said["error-aware"] == said["paper"] == 0:
        head = (f"no difference at any of the {len(shared)} budget(s) (the captured shares' 90% intervals "
                f"overlap, or there is no oracle)")
    else:
        head = (f"the error-aware relevance captures more at {said['error-aware']}, the paper's at "
                f"{said['paper']}, no difference at {said[captured.NO_DIFFERENCE]} of the {len(shared)} budget(s)")
    flip_paper = float(np.mean([paper[f]["flip"] for f in shared]))
    flip_error = float(np.mean([error[f]["flip"] for f in shared]))
    lower = sum(1 for f in shared if error[f]["flip"] < paper[f]["flip"])
    higher = sum(1 for f in shared if error[f]["flip"] > paper[f]["flip"])
    change = (flip_error - flip_paper) / flip_paper if flip_paper > 0 else None
    text = (f"{head}; mean LDR-FLIP over the budgets {flip_paper:.3f} with the paper's R, "
            f"{flip_error:.3f} with the error-aware R"
            + (f" ({100 * change:+.0f}%)" if change is not None else "")
            + f"; the error-aware R is lower at {lower} and higher at {higher} of them")
    shares = [(paper[f]["captured"], error[f]["captured"]) for f in shared
              if paper[f].get("captured") is not None and error[f].get("captured") is not None]
    if shares:
        text += (f"; captured {np.mean([a for a, _ in shares]):.2f} (paper R) against "
                 f"{np.mean([b for _, b in shares]):.2f} (error-aware R) of the oracle's error reduction")
    return text + ".", change


def _judged(row):
    return captured.Captured(share=row.get("captured"), low=row.get("captured_lo"), high=row.get("captured_hi"))


def _relevance_comparison(scene, path, paper, error):
    """The paper's relevance against the error-aware one at each budget both ran."""
    table = []
    for fraction in sorted(set(paper) & set(error)):
        a, b = paper[fraction], error[fraction]
        change = None
        if a["flip"] and b["flip"] is not None:
            change = 100.0 * (b["flip"] - a["flip"]) / a["flip"]
        table.append([f"{fraction:.2f}", _number(a["budget_ms"], ".1f"), _number(a["flip"], ".4f"),
                      _number(b["flip"], ".4f"), _signed(change, ".1f") + ("%" if change is not None else ""),
                      _number(a["regret"], ".4f"), _number(b["regret"], ".4f"),
                      _number(a["popping"], ".4f"), _number(b["popping"], ".4f")])
    verdict, _ = relevance_verdict(paper, error)
    return [("table", ReportTable(
        f"Paper relevance against error-aware relevance: {scene} / {path}",
        ["Budget at", "Budget ms", "LDR-FLIP, paper R", "LDR-FLIP, error-aware R", "Change",
         "Regret, paper R", "Regret, error-aware R", "Popping / 100, paper R", "Popping / 100, error-aware R"],
        table,
        "Both with the measured cost model, I = 0.5 and the paper's greedy order; the error-aware relevance "
        "weights V by each element's running estimate of its traced-vs-raster difference per pixel "
        f"(a prior from its material before it is first traced). On {scene} / {path}, " + verdict))]
