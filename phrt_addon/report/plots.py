"""The report's plots (matplotlib Figures saved by the Agg canvas: no pyplot, no global backend).
"""
import numpy as np

from .runs import BASELINE_VARIANT, pareto_front
from .selection import variant_label


def _figure(**kwargs):
    """A matplotlib Figure drawn by the Agg canvas, without pyplot's global state."""
    from matplotlib.figure import Figure

    return Figure(**kwargs)


def plot_error_vs_time(path, groups, errors):
    """One row per (scene, path) (errors of different paths do not compare): mean LDR-FLIP
    and mean relMSE against mean frame time."""
    figure = _figure(figsize=(16, 7.5 * len(groups)))
    panels = figure.subplots(len(groups), 2, squeeze=False)
    for row, (group, members) in enumerate(groups.items()):
        _plot_curves(panels[row, 0], group, members, errors, "flip",
                     "mean LDR-FLIP against the reference (lower is better)")
        _plot_curves(panels[row, 1], group, members, errors, "relmse",
                     "mean relMSE against the reference (lower is better)")
    figure.tight_layout()
    figure.savefig(path, dpi=100)
    return figure


def _variant_styles(members):
    """{variant: (colour, line width, label)}: the paper's heuristic first and boldest."""
    variants = sorted({run.variant for run in members if run.mode == "HYBRID"},
                      key=lambda v: (v != BASELINE_VARIANT, v[3] != "paper", v))
    colours = ["tab:blue", "tab:red", "tab:green", "tab:orange", "tab:purple", "tab:brown", "tab:pink",
               "tab:olive", "tab:cyan", "tab:gray"]
    return {variant: (colours[index % len(colours)], 2.2 if variant == BASELINE_VARIANT else 1.3,
                      variant_label(variant)) for index, variant in enumerate(variants)}


def _plot_curves(axes, group, members, errors, key, ylabel):
    axes.set_title(f"{group[0]} / {group[1]}: {ylabel.split(' against')[0]} against frame time")
    axes.set_xlabel("steady mean frame time, frames after the first (ms)")
    axes.set_ylabel(ylabel)
    axes.grid(True, alpha=0.3)
    points = [(run, run.steady("mean"), errors[id(run)].mean(key)) for run in members]
    points = [(run, time, error) for run, time, error in points if time is not None and error is not None]
    if not points:
        axes.text(0.5, 0.5, "no error measured for this path\n(see the error table)",
                  ha="center", va="center", transform=axes.transAxes)
        return
    times = np.array([time for _, time, _ in points])
    values = np.array([error for _, _, error in points])
    ends = {mode: next(((time, error) for run, time, error in points if run.mode == mode), None)
            for mode in ("RASTER", "RAYTRACE")}
    styles = _variant_styles([run for run, _, _ in points])
    budgets = {}
    for variant, (colour, width, label) in styles.items():
        curve = sorted(((run.budget_at if run.budget_at is not None else -1.0, time, error, run)
                        for run, time, error in points if run.mode == "HYBRID" and run.variant == variant),
                       key=lambda item: (item[0], item[1]))
        xs = [item[1] for item in curve]
        ys = [item[2] for item in curve]
        line_x = ([ends["RASTER"][0]] if ends["RASTER"] else []) + xs + ([ends["RAYTRACE"][0]] if ends["RAYTRACE"] else [])
        line_y = ([ends["RASTER"][1]] if ends["RASTER"] else []) + ys + ([ends["RAYTRACE"][1]] if ends["RAYTRACE"] else [])
        axes.plot(line_x, line_y, color=colour, linewidth=width, alpha=0.85, zorder=2)
        axes.scatter(xs, ys, color=colour, s=36, zorder=4, label=label)
        for _, time, error, run in curve:
            budget = run.summary.get("budget_ms")
            if budget:
                budgets.setdefault(round(float(budget), 3), run.budget_at)
                # The budget mark: a tick at the budget, joined to the point it belongs to.
                axes.plot([budget, time], [error, error], color=colour, linestyle=":", linewidth=0.9, zorder=1)
                axes.scatter([budget], [error], marker="|", s=160, color=colour, zorder=3)
    for mode, marker, label in (("RASTER", "s", "raster"), ("RAYTRACE", "D", "ray traced (reference)")):
        if ends[mode]:
            axes.scatter([ends[mode][0]], [ends[mode][1]], marker=marker, s=60, color="black", zorder=5,
                         label=label)
    if len(points) <= 5:  # few runs: name them
        for run, time, error in points:
            axes.annotate(run.label, (time, error), fontsize=8, textcoords="offset points", xytext=(6, 6))
    front = pareto_front(times, values)
    axes.plot(times[front], values[front], color="0.35", drawstyle="steps-post", linestyle="--",
              linewidth=1.2, label="Pareto front", zorder=1)
    top = float(values.max()) if values.max() > 0 else 1.0
    for budget, fraction in sorted(budgets.items()):
        axes.axvline(budget, color="tab:red", linestyle=":", linewidth=0.8, alpha=0.6)
        text = f"budget {budget:.0f} ms" + (f" (at {fraction:.2f})" if fraction is not None else "")
        axes.annotate(text, (budget, 1.0), xycoords=("data", "axes fraction"), xytext=(3, -4),
                      textcoords="offset points", fontsize=7, color="tab:red", rotation=90, va="top")
    axes.scatter([], [], marker="|", s=100, color="0.3", label="budget of a hybrid point (dotted to it)")
    axes.set_xlim(0.0, 1.08 * max(float(times.max()), *budgets.keys(), 1.0))
    axes.set_ylim(0.0, 1.18 * top)
    axes.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.11), ncol=3, frameon=False)


def plot_selection_quality(path, groups, regrets, pops):
    """Per (scene, path): mean regret against the oracle and popping per 100 frames, against the budget."""
    hybrid_groups = {group: [run for run in members if run.mode == "HYBRID"] for group, members in groups.items()}
    hybrid_groups = {group: members for group, members in hybrid_groups.items() if members}
    figure = _figure(figsize=(16, 5.5 * len(hybrid_groups)))
    panels = figure.subplots(len(hybrid_groups), 2, squeeze=False)
    for row, (group, members) in enumerate(hybrid_groups.items()):
        styles = _variant_styles(members)
        for axes, title, ylabel, value_of in (
                (panels[row, 0], "regret against the oracle",
                 "mean regret: LDR-FLIP(heuristic) - LDR-FLIP(oracle)",
                 lambda run: regrets.get(id(run)).mean if regrets.get(id(run)) else None),
                (panels[row, 1], "popping", "popping per 100 frames (summed LDR-FLIP excess)",
                 lambda run: pops[id(run)].per_100_frames() if id(run) in pops else None)):
            axes.set_title(f"{group[0]} / {group[1]}: {title}")
            axes.set_xlabel("frame budget (ms)")
            axes.set_ylabel(ylabel)
            axes.grid(True, alpha=0.3)
            axes.axhline(0.0, color="0.4", linewidth=0.8)
            drawn = False
            for variant, (colour, width, label) in styles.items():
                curve = sorted((run.summary.get("budget_ms"), value_of(run)) for run in members
                               if run.variant == variant and run.summary.get("budget_ms") is not None
                               and value_of(run) is not None)
                if curve:
                    drawn = True
                    axes.plot([x for x, _ in curve], [y for _, y in curve], marker="o", color=colour,
                              linewidth=width, label=label)
            if drawn:
                axes.legend(fontsize=7, loc="best")
            else:
                axes.text(0.5, 0.5, "not measured (see the report's notes)", ha="center", va="center",
                          transform=axes.transAxes)
    figure.tight_layout()
    figure.savefig(path, dpi=100)
    return figure


def plot_timeline(path, groups):
    figure = _figure(figsize=(10, 5.5 * len(groups)))
    axes = figure.subplots(2 * len(groups), 1, squeeze=False,
                           gridspec_kw={"height_ratios": [2, 1] * len(groups)})
    for index, (group, members) in enumerate(groups.items()):
        time_axes, selected_axes = axes[2 * index, 0], axes[2 * index + 1, 0]
        budgeted = [run for run in members if run.mode == "HYBRID"] or members[:1]
        for run in members:
            frames, total = run.column("total_ms")
            line, = time_axes.plot(frames, total, linewidth=1.2,
                                   label=f"{run.label} ({run.mode.lower()})")
            frames, selected = run.column("n_selected")
            selected_axes.step(frames, selected, where="mid", linewidth=1.2,
                               color=line.get_color())
            frames, budget = run.column("budget_ms")
            if run in budgeted and budget.size:
                time_axes.step(frames, budget, where="mid", color=line.get_color(),
                               linestyle="--", linewidth=1.0,
                               label=f"budget of {run.label} ({budget[-1]:g} ms)")
        time_axes.set_title(f"{group[0]} / {group[1]}")
        time_axes.set_ylabel("frame time (ms)")
        time_axes.set_ylim(0.0, 1.1 * max([1.0] + [float(line.get_ydata().max())
                                                  for line in time_axes.get_lines()
                                                  if len(line.get_ydata())]))
        time_axes.grid(True, alpha=0.3)
        time_axes.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
        selected_axes.set_ylabel("selected elements")
        selected_axes.set_xlabel("frame")
        selected_axes.set_ylim(bottom=0.0)
        selected_axes.yaxis.get_major_locator().set_params(integer=True)
        selected_axes.xaxis.get_major_locator().set_params(integer=True)
        time_axes.xaxis.get_major_locator().set_params(integer=True)
        selected_axes.grid(True, alpha=0.3)
        selected_axes.sharex(time_axes)
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    return figure
