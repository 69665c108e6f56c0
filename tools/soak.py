"""``make soak``: long runs that are too slow for ``make test``.

1. A 1000-frame HYBRID replay of a sample scene (default: arcade, path1, 320x240, budget
   600 ms: about twice the raster frame there, so elements are traced), in this process
   through the same replay code as ``phrt render``.  Resident memory (VmRSS) is sampled
   after every frame: the run passes when RSS after frame 1000 is less than 50 MB above RSS
   after frame 100 (the first frames warm caches: shaders, Embree scenes, shadow maps).
   Every GPU object (textures, frame buffers, vertex/index buffers, batches, uniform
   buffers, offscreens, shaders) and every Embree scene the engine creates is counted, and
   counted again when the engine lets go of it; after the replay and ``release_caches()``
   the two counts must be equal.
2. A 2-million-triangle mesh (a displaced 1000 x 1000 grid, a ray tracing candidate with
   shadows and reflections, beside a mirror sphere) rendered in RASTER, HYBRID and RAYTRACE
   mode, two frames each: it must render (or be refused with a clear message) without hanging;
   the stage times and peak memory are reported.

Writes ``<out>/soak.json`` and prints the figures; exit status 1 if a criterion fails.
"""
from __future__ import annotations

import argparse
import gc
import json
import math
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
RSS_GROWTH_LIMIT_MB = 50.0


def rss_mb() -> float:
    with open("/proc/self/status", encoding="ascii") as status:
        for line in status:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    return float("nan")


def peak_rss_mb() -> float:
    with open("/proc/self/status", encoding="ascii") as status:
        for line in status:
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024.0
    return float("nan")


class ResourceCounter:
    """Counts GPU objects and Embree scenes: created when a constructor returns, freed once
    nothing but this counter refers to them any more (CPython reference counts; these types
    take no weak references).  The counter keeps each object alive until the next ``collect()``,
    which only delays its release by a frame."""

    GPU_TYPES = ("GPUTexture", "GPUFrameBuffer", "GPUOffScreen", "GPUVertBuf", "GPUIndexBuf", "GPUBatch",
                 "GPUUniformBuf")

    def __init__(self):
        self.created = {}
        self.freed = {}
        self._live = []  # (kind, object)
        self._restore = []

    def _wrap(self, owner, name, kind):
        original = getattr(owner, name)

        def create(*args, **kwargs):
            made = original(*args, **kwargs)
            self.created[kind] = self.created.get(kind, 0) + 1
            self._live.append((kind, made))
            return made

        setattr(owner, name, create)
        self._restore.append((owner, name, original))

    def install(self):
        import gpu

        from phrt.phrt_addon.trace import embree_scene
        for name in self.GPU_TYPES:
            self._wrap(gpu.types, name, name)
        self._wrap(gpu.shader, "create_from_info", "GPUShader")
        # Embree scenes: embreex checks their type, so the tracer's owner of each is wrapped instead.
        original_init = embree_scene.EmbreeSet.__init__

        def init(embree_set, *args, **kwargs):
            original_init(embree_set, *args, **kwargs)
            self.created["EmbreeScene"] = self.created.get("EmbreeScene", 0) + 1
            self._live.append(("EmbreeScene", embree_set.scene))

        embree_scene.EmbreeSet.__init__ = init
        self._restore.append((embree_scene.EmbreeSet, "__init__", original_init))
        return self

    def uninstall(self):
        for owner, name, original in reversed(self._restore):
            setattr(owner, name, original)
        self._restore = []

    def collect(self):
        """Count the objects nothing else refers to any more as freed (and let them go).  Repeated
        until nothing more goes: a batch let go here releases the vertex and index buffers it held,
        which an earlier look in the same pass still saw referenced."""
        while True:
            gc.collect()
            still = []
            made = None
            for kind, made in self._live:
                # References: the list entry, the loop variable and getrefcount's argument.
                if sys.getrefcount(made) <= 3:
                    self.freed[kind] = self.freed.get(kind, 0) + 1
                else:
                    still.append((kind, made))
            del made
            released = len(self._live) - len(still)
            self._live = still
            if released == 0:
                return len(still)

    def report(self):
        kinds = sorted(set(self.created) | set(self.freed))
        return {kind: {"created": self.created.get(kind, 0), "freed": self.freed.get(kind, 0)} for kind in kinds}

    @property
    def balanced(self):
        return all(self.created.get(kind, 0) == self.freed.get(kind, 0) for kind in self.created)


def long_replay(args, counter, out):
    import bpy

    from phrt.cli import blender_process
    from phrt.engine import final
    from phrt.engine.runs import replay
    from phrt.engine.runs import camera_path

    label = blender_process.load_scene(args.scene)
    scene = bpy.context.scene
    camera = camera_path.find_path(scene, args.path)
    start, end = camera_path.path_frame_range(scene, camera)
    frames = (start, start + args.frames - 1)
    samples = []
    started = time.perf_counter()

    def progress(done, total, frame_ms):
        live = counter.collect()
        samples.append({"frame": done, "rss_mb": rss_mb(), "frame_ms": frame_ms, "live_objects": live})
        if done % 50 == 0 or done == total:
            elapsed = time.perf_counter() - started
            print(f"  frame {done}/{total}: {frame_ms:6.0f} ms, RSS {samples[-1]['rss_mb']:7.1f} MB, "
                  f"{live} GPU/Embree objects alive, {elapsed:6.0f} s", file=sys.stderr, flush=True)

    with blender_process.quiet_stdout():  # Blender's "Saved: ..." line per frame
        result = replay.replay(scene, camera, frames, "HYBRID", out / f"{label}-{camera.name}-hybrid",
                               images="exr", budget_ms=args.budget_ms, resolution=args.resolution,
                               scene_label=label, on_progress=progress, overwrite=True)
    wall_s = time.perf_counter() - started
    final.release_caches()
    alive_after = counter.collect()
    by_frame = {sample["frame"]: sample for sample in samples}
    early = by_frame.get(min(100, len(samples)), samples[0])
    last = samples[-1]
    summary = result.summary or {}
    return {
        "scene": label, "path": camera.name, "frames": result.frames_done, "frame_range": list(frames),
        "resolution": list(args.resolution), "budget_ms": args.budget_ms, "wall_s": wall_s,
        "mean_total_ms": summary.get("total_ms", {}).get("mean"), "p95_total_ms": summary.get("total_ms", {}).get("p95"),
        "mean_selected": summary.get("mean_n_selected"),
        "rss_mb_after_frame_100": early["rss_mb"], "rss_mb_after_last_frame": last["rss_mb"],
        "rss_growth_mb": last["rss_mb"] - early["rss_mb"], "rss_max_mb": max(s["rss_mb"] for s in samples),
        "objects_alive_after_release": alive_after, "resources": counter.report(),
        "rss_every_100_frames": [by_frame[f]["rss_mb"] for f in sorted(by_frame) if f % 100 == 0],
    }


def big_mesh_scene(triangles, resolution):
    """A displaced grid of ``triangles`` triangles (a candidate with shadows and reflections),
    a mirror sphere and a floor, a sun and a point light, a camera path of two frames."""
    import bmesh
    import bpy
    import numpy as np

    from phrt.sample_scenes import showcase

    scene = showcase.empty_scene(*resolution)
    scene.phrt.shadow_map_size = 1024
    showcase.mesh_object("Floor", showcase.plane(40.0), showcase.principled("Floor", (0.5, 0.5, 0.5)))
    segments = int(math.sqrt(triangles / 2))
    mesh = bpy.data.meshes.new("Terrain")
    bm = bmesh.new()
    bmesh.ops.create_grid(bm, x_segments=segments, y_segments=segments, size=4.0)
    bm.to_mesh(mesh)
    bm.free()
    count = len(mesh.vertices)
    co = np.empty(count * 3, np.float32)
    mesh.vertices.foreach_get("co", co)
    co = co.reshape(-1, 3)
    co[:, 2] = 0.6 + 0.25 * np.sin(co[:, 0] * 3.1) * np.cos(co[:, 1] * 2.3) + 0.05 * np.sin(co[:, 0] * 37.0)
    mesh.vertices.foreach_set("co", co.ravel())
    mesh.update()
    mesh.materials.append(showcase.principled("Terrain", (0.4, 0.6, 0.3), metallic=0.3, roughness=0.2))
    terrain = bpy.data.objects.new("Terrain", mesh)
    scene.collection.objects.link(terrain)
    showcase.tag(terrain, shadows=True, reflections=True, refractions=False)
    sphere = showcase.mesh_object("Mirror", showcase.sphere(0.5), showcase.principled(
        "Mirror", (0.9, 0.9, 0.9), metallic=1.0, roughness=0.0), location=(0.0, -2.5, 1.5), smooth=True)
    showcase.tag(sphere, shadows=True, reflections=True, refractions=False)
    showcase.add_light("SUN", (0, 0, 5), 3.0, rotation=(math.radians(40), 0.0, math.radians(30)), name="Sun")
    showcase.add_light("POINT", (1.0, -3.0, 3.0), 300.0, name="Lamp")
    camera = showcase.add_camera((3.0, -7.0, 4.0), (0.0, 0.0, 0.6))
    camera.keyframe_insert("location", frame=1)
    camera.location.x -= 0.5
    camera.keyframe_insert("location", frame=2)
    return scene, len(mesh.polygons) * 2


def big_mesh(args, counter, out):
    from phrt.cli import blender_process
    from phrt.engine import final
    from phrt.engine.runs import replay
    from phrt.engine.runs import camera_path

    started = time.perf_counter()
    scene, triangles = big_mesh_scene(args.triangles, args.resolution)
    build_s = time.perf_counter() - started
    runs = {}
    for mode in ("RASTER", "HYBRID", "RAYTRACE"):
        begin = time.perf_counter()
        try:
            with blender_process.quiet_stdout():
                replay.replay(scene, scene.camera, (1, 2), mode, out / f"big-{mode.lower()}", images="exr",
                              budget_ms=1e9 if mode != "RASTER" else None, scene_label="big", overwrite=True)
        except camera_path.ReplayError as error:
            runs[mode] = {"refused": str(error)}
            continue
        from phrt.phrt_addon.runs import run_files
        rows = run_files.read_frames(out / f"big-{mode.lower()}")
        runs[mode] = {
            "wall_s": time.perf_counter() - begin,
            "frames": [{key: row.get(key) for key in ("total_ms", "raster_ms", "trace_ms", "composite_ms",
                                                      "extract_ms", "gpu_upload_ms", "upload_ms", "rays",
                                                      "n_selected")} for row in rows],
        }
        final.release_caches()
        counter.collect()
    return {"triangles": triangles, "scene_build_s": build_s, "runs": runs, "peak_rss_mb": peak_rss_mb(),
            "resources": counter.report(), "objects_alive_after_release": counter.collect()}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="arcade")
    parser.add_argument("--path", default=None)
    parser.add_argument("--frames", type=int, default=1000)
    parser.add_argument("--resolution", default="320x240")
    parser.add_argument("--budget-ms", type=float, default=600.0)
    parser.add_argument("--triangles", type=int, default=2_000_000)
    parser.add_argument("--out", default=str(ROOT / "out" / "soak"))
    parser.add_argument("--skip-replay", action="store_true")
    parser.add_argument("--skip-big-mesh", action="store_true")
    args = parser.parse_args(argv)
    args.resolution = tuple(int(part) for part in args.resolution.lower().split("x"))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    from phrt.cli import blender_process
    blender_process.blender()
    counter = ResourceCounter().install()
    report = {"rss_growth_limit_mb": RSS_GROWTH_LIMIT_MB}
    failures = []
    try:
        if not args.skip_replay:
            print(f"soak: {args.frames}-frame HYBRID replay of {args.scene} at {args.resolution[0]}x"
                  f"{args.resolution[1]}, budget {args.budget_ms:g} ms", flush=True)
            replay_report = long_replay(args, counter, out)
            report["replay"] = replay_report
            if replay_report["frames"] != args.frames:
                failures.append(f"replay rendered {replay_report['frames']} of {args.frames} frames")
            if not replay_report["rss_growth_mb"] < RSS_GROWTH_LIMIT_MB:
                failures.append(f"RSS grew {replay_report['rss_growth_mb']:.1f} MB from frame 100 to the last")
            if not counter.balanced or replay_report["objects_alive_after_release"]:
                failures.append(f"GPU/Embree objects created != freed: {counter.report()}")
        if not args.skip_big_mesh:
            print(f"soak: a {args.triangles:,}-triangle mesh in raster, hybrid and raytrace mode", flush=True)
            report["big_mesh"] = big_mesh(args, counter, out)
            for mode, run in report["big_mesh"]["runs"].items():
                if "refused" in run:
                    print(f"  {mode}: refused: {run['refused']}")
                else:
                    frame = run["frames"][-1]
                    print(f"  {mode}: {run['wall_s']:.1f} s for 2 frames; last frame total {frame['total_ms']:.0f} ms "
                          f"(raster {frame['raster_ms']:.0f}, trace {frame['trace_ms']:.0f}, extract "
                          f"{frame['extract_ms']:.0f}, Embree upload {frame['upload_ms']:.0f})", flush=True)
            if not counter.balanced:
                failures.append(f"GPU/Embree objects created != freed after the big mesh: {counter.report()}")
    finally:
        counter.uninstall()
    report["failures"] = failures
    (out / "soak.json").write_text(json.dumps(report, indent=2, default=float) + "\n")
    if "replay" in report:
        r = report["replay"]
        print(f"soak: RSS after frame 100 {r['rss_mb_after_frame_100']:.1f} MB, after frame {r['frames']} "
              f"{r['rss_mb_after_last_frame']:.1f} MB (growth {r['rss_growth_mb']:+.1f} MB, limit "
              f"{RSS_GROWTH_LIMIT_MB:g}), max {r['rss_max_mb']:.1f} MB; mean frame {r['mean_total_ms']:.0f} ms; "
              f"wall {r['wall_s']:.0f} s")
        print("soak: resources " + ", ".join(f"{kind} {counts['created']}/{counts['freed']}"
                                             for kind, counts in r["resources"].items()) + " (created/freed)")
    print(f"soak: {'FAILED: ' + '; '.join(failures) if failures else 'passed'} -> {out / 'soak.json'}")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
