"""``make rate-flip``: what each quality-tier rate loses, per effect, on the judged paths (issue 23).

For each judged path (the selection work's: arcade path3, atrium path2-3, the orbiting showcase),
every ``--every``-th frame of ``--frames`` is rendered through the real engine (HYBRID, every
visible candidate traced, ``FrameRenderer.forced_selection``) at full rate, then with one effect
at half and at quarter rate (the other effects at full).  Each is compared with the full-rate
frame by LDR-FLIP over the whole frame and over the pixels the reduced effect covers there (its
``PHRT Rate`` below 1: the pixels reconstructed or traced at that rate).  Writes
``OUT/rate_flip.csv`` / ``.md`` and ``OUT/rates_<path>_<frame>.png`` (the first sampled frame of
each path: every effect at full, half and quarter rate, and the rate pass).

    python tools/rate_flip.py [--out out/rate-flip] [--frames 1-200] [--every 20]
        [--paths arcade/path3,...] [--resolution 320x240] [--showcase out/selection-eval/showcase.blend]
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

EFFECTS = ("shadows", "reflections", "refractions")
REDUCED = (0.5, 0.25)
COLUMNS = ("path", "effect", "rate", "frames", "pixels", "flip_frame", "flip_pixels", "flip_pixels_max")


def _mean(values):
    return float(np.mean(values)) if values else float("nan")


def measure_path(scene_name, path, frames, every, resolution, out, label):
    from phrt.cli import blender_process
    from phrt.engine.runs import camera_path
    from phrt.engine.runs.oracle import ForcedRenderer, competing_candidates
    from phrt.phrt_addon.report import metrics

    blender_process.load_scene(scene_name)
    import bpy
    scene = bpy.context.scene
    camera = camera_path.find_path(scene, path)
    sampled = list(range(frames[0], frames[1] + 1, every))
    found = {(effect, rate): {"frame": [], "pixels": [], "count": []} for effect in EFFECTS for rate in REDUCED}
    pictured = False
    with ForcedRenderer(scene, camera, resolution) as renderer:
        renderer.render(sampled[0], ())  # warm-up: shaders, shadow maps, Embree scenes
        for frame in sampled:
            _, _, selection = renderer.render(frame, ())
            names = competing_candidates(selection)
            if not names:
                continue
            full, _, _ = renderer.render(frame, names)
            pictures = {1.0: full}
            for rate in REDUCED:
                everything, _, _ = renderer.render(frame, names, {effect: rate for effect in EFFECTS})
                pictures[rate] = (everything, np.asarray(renderer.last_passes.rate)[::-1])
                for effect in EFFECTS:
                    image, _, _ = renderer.render(frame, names, {effect: rate})
                    effect_rate = (renderer.last_passes.effect_rate or {}).get(effect)
                    if effect_rate is None:
                        continue
                    effect_rate = np.asarray(effect_rate)[::-1]
                    reduced = (effect_rate > 0.0) & (effect_rate < 1.0)  # this effect's pixels at that rate
                    entry = found[(effect, rate)]
                    flip_map = metrics.flip_map(full, image)
                    entry["frame"].append(float(flip_map.mean()))
                    if reduced.any():
                        entry["pixels"].append(float(flip_map[reduced].mean()))
                        entry["count"].append(int(reduced.sum()))
            if not pictured:  # the first sampled frame with candidates in view
                _picture(out / f"rates_{label}_{frame:04d}.png", pictures, f"{label} frame {frame}")
                pictured = True
    rows = []
    for (effect, rate), entry in found.items():
        rows.append({"path": label, "effect": effect, "rate": rate, "frames": len(entry["frame"]),
                     "pixels": int(np.mean(entry["count"])) if entry["count"] else 0,
                     "flip_frame": _mean(entry["frame"]), "flip_pixels": _mean(entry["pixels"]),
                     "flip_pixels_max": max(entry["pixels"]) if entry["pixels"] else float("nan")})
    return rows


def _picture(path, pictures, title):
    import matplotlib
    matplotlib.use("Agg")
    from matplotlib import pyplot as plt

    from phrt.phrt_addon.report import metrics
    figure, axes = plt.subplots(1, 4, figsize=(16, 3.6))
    axes[0].imshow(metrics.tonemap(pictures[1.0]))
    axes[0].set_title("every effect at full rate")
    for axis, rate in zip(axes[1:3], REDUCED):
        axis.imshow(metrics.tonemap(pictures[rate][0]))
        axis.set_title(f"every effect at {rate:g}")
    rate_pass = pictures[REDUCED[-1]][1]
    shown = axes[3].imshow(rate_pass if rate_pass is not None else np.zeros((2, 2)), vmin=0, vmax=1, cmap="viridis")
    axes[3].set_title(f"PHRT Rate at {REDUCED[-1]:g} (0: raster)")
    figure.colorbar(shown, ax=axes[3], fraction=0.046)
    for axis in axes:
        axis.set_axis_off()
    figure.suptitle(title)
    figure.tight_layout()
    figure.savefig(path, dpi=90)
    plt.close(figure)


def markdown(rows) -> str:
    lines = ["| Path | Effect | Rate | Frames | Pixels at that rate | LDR-FLIP (frame) | LDR-FLIP (its pixels) "
             "| worst frame (its pixels) |", "|---|---|---|---|---|---|---|---|"]
    for row in rows:
        cells = [row["path"], row["effect"], f"{row['rate']:g}", str(row["frames"]), str(row["pixels"])]
        cells += ["–" if not np.isfinite(row[key]) else f"{row[key]:.4f}"
                  for key in ("flip_frame", "flip_pixels", "flip_pixels_max")]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description="LDR-FLIP of each quality-tier rate against full rate")
    parser.add_argument("--out", default="out/rate-flip")
    parser.add_argument("--frames", default="1-200")
    parser.add_argument("--every", type=int, default=20)
    parser.add_argument("--paths", default="arcade/path3,atrium/path2,atrium/path3,showcase/orbit")
    parser.add_argument("--resolution", default="320x240")
    parser.add_argument("--showcase", default="out/selection-eval/showcase.blend",
                        help="the orbiting showcase scene (written by tools/selection_eval.py)")
    args = parser.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    parts = [int(part) for part in args.frames.split("-")]
    frames = (parts[0], parts[-1])
    resolution = tuple(int(part) for part in args.resolution.split("x"))
    rows = []
    for target in args.paths.split(","):
        scene, path = target.split("/")
        if scene == "showcase":
            if not Path(args.showcase).is_file():
                print(f"rate-flip: {args.showcase} missing (run make selection-eval first): showcase skipped",
                      file=sys.stderr)
                continue
            scene = str(Path(args.showcase).resolve())
        rows += measure_path(scene, path, frames, args.every, resolution, out, target.replace("/", "-"))
    from selection_eval import write_table  # its sibling in tools/
    write_table(out, "rate_flip", COLUMNS, rows, markdown(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
