"""The trace stage of this checkout against another one's on the same frames, in one process:
frames captured from a BENEFIT replay (the largest of each mix of traced effects), each traced
alternately by both stages, each from its own ``LayerPixels`` made from the read-back layers
(what the frame's trace time holds after the read-back itself); prints the median ms of each
and checks that both give the same traced values and ray counts.

    .venv/bin/python tools/trace_ab.py arcade --old /path/to/other/checkout [--budget-ms 200]
        [--frames 1-60] [--resolution 320x240] [--repeats 12] [--pick most|fewest] [--force NAME,...]

``--force`` traces those elements on every frame (the oracle's forced selection) instead of the
BENEFIT choice: ``atrium --force Tree_Oak --frames 40-60`` times the oak's shadows, 34,700 rays.
``--rate 0.25`` (or 0.5) traces every effect of the captured frames at that rate (quality tiers):
``atrium --force Tree_Oak --frames 40-44 --rate 0.25`` times the oak's quarter-rate shadows and
their reconstruction.

Only ``phrt_addon`` of the other checkout is imported (as ``phrt_old``): its stage must take
this checkout's snapshots (true of the trace stage since 203265f)."""
from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def capture(args):
    """{mix of traced effects: (args, kwargs, rays)} of the frames with the most rays."""
    from phrt.phrt_addon import frame
    from phrt.phrt_addon.trace import stage
    from profile_frame import replay_scene  # tools/: the scene loaded and its path replayed
    captured = {}
    run = stage.TraceStage.run
    layer_pixels = frame.LayerPixels

    def recorded(*a, **k):  # each layer's LayerPixels arguments, to make it again for each run
        pixels = layer_pixels(*a, **k)
        pixels.made_from = (a, k)
        return pixels

    def keep(self, *a, **k):
        result = run(self, *a, **k)
        counters = result.counters
        rays = (counters.shadow_rays, counters.reflection_rays, counters.refraction_rays)
        mix = "+".join(name for name, count in zip(("shadows", "reflections", "refractions"), rays) if count)
        better = (lambda new, old: new < old) if args.pick == "fewest" else (lambda new, old: new > old)
        if mix and (mix not in captured or better(sum(rays), captured[mix][2])):
            captured[mix] = (a, k, sum(rays))
        return result

    init = frame.FrameRenderer.__init__

    def forcing(self, *a, **k):
        init(self, *a, **k)
        self.forced_selection = frozenset(args.force.split(","))

    stage.TraceStage.run = keep
    frame.LayerPixels = recorded
    if args.force:
        frame.FrameRenderer.__init__ = forcing
    width, height = (int(v) for v in args.resolution.lower().split("x"))
    try:
        replay_scene(args.scene, "HYBRID", args.frames, width, height, args.budget_ms, {"selection": "BENEFIT"})
    finally:
        stage.TraceStage.run = run
        frame.LayerPixels = layer_pixels
        frame.FrameRenderer.__init__ = init
    return captured


def made_again(args, layer_pixels):
    """The stage's arguments with each layer made again by ``layer_pixels`` (a module's class)."""
    layers = {name: layer_pixels(*pixels.made_from[0], **pixels.made_from[1]) for name, pixels in args[1].items()}
    return (args[0], layers) + tuple(args[2:])


def same(new, old, reduced=False):
    """Both results trace the same values (to 1e-6) and count the same rays: True, False, or at a
    reduced rate (``reduced``: the reconstruction may fill other pixels) the pixels this checkout
    fills beyond the other's, when the rays are the same and the values where both fill agree to 1e-4
    (the reconstruction weighs in float32 since 266eeda)."""
    a, b = new.traced, old.traced
    pairs = [(a.shadow_visibility.get(key), b.shadow_visibility.get(key)) for key in
             set(a.shadow_visibility) | set(b.shadow_visibility)]
    pairs += [(a.reflection.get(key), b.reflection.get(key)) for key in set(a.reflection) | set(b.reflection)]
    pairs.append((a.refraction, b.refraction))
    extra = 0
    for x, y in pairs:
        if (x is None) != (y is None):
            return False
        if x is None:
            continue
        if reduced:
            both, at_x, at_y = np.intersect1d(x[0], y[0], return_indices=True)
            if not np.allclose(x[1][at_x], y[1][at_y], rtol=0, atol=1e-4):  # float32 weights: to 1e-4
                return False
            extra += len(x[0]) - len(both)
        elif not (np.array_equal(x[0], y[0]) and np.allclose(x[1], y[1], rtol=0, atol=1e-6)):
            return False
    c, d = new.counters, old.counters
    if (c.shadow_rays, c.reflection_rays, c.refraction_rays) != (d.shadow_rays, d.reflection_rays, d.refraction_rays):
        return False
    return extra if reduced else True


def verdict(result) -> str:
    if result is True:
        return "same values and rays"
    if result is False:
        return "DIFFERENT values or rays"
    return f"same rays and values where both fill ({result} pixels more filled here)"


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scene")
    parser.add_argument("--old", required=True, help="another checkout of this repository")
    parser.add_argument("--budget-ms", type=float, default=200.0)
    parser.add_argument("--frames", default="1-60")
    parser.add_argument("--resolution", default="320x240")
    parser.add_argument("--repeats", type=int, default=12)
    parser.add_argument("--pick", choices=("most", "fewest"), default="most",
                        help="of each mix, the frame with the most rays or the fewest (the fixed part)")
    parser.add_argument("--force", default=None, help="elements traced on every frame (comma-separated names)")
    parser.add_argument("--rate", type=float, default=None, help="every effect traced at this rate (0.25, 0.5, 1)")
    args = parser.parse_args(argv)
    links = Path(tempfile.mkdtemp(prefix="phrt-ab-"))
    (links / "phrt_old").symlink_to(Path(args.old).resolve(), target_is_directory=True)
    sys.path.insert(0, str(links))
    from phrt_old.phrt_addon.trace import stage as old_stage
    from phrt_old.phrt_addon import frame_types as old_types
    from phrt.phrt_addon.trace import stage as new_stage
    from phrt.phrt_addon import frame_types as new_types
    captured = capture(args)
    new, old = new_stage.TraceStage(None), old_stage.TraceStage(None)
    print(f"{args.scene} at {args.resolution}, budget {args.budget_ms:g} ms"
          f"{'' if args.rate is None else f', every effect at rate {args.rate:g}'}: trace stage ms, medians of "
          f"{args.repeats} alternate runs (this checkout / {args.old})")
    try:
        for mix, (a, k, rays) in sorted(captured.items()):
            if args.rate is not None:
                k = dict(k, rates={effect: np.full(len(a[0].elements), args.rate)
                                   for effect in ("shadows", "reflections", "refractions")})
            new.run(*made_again(a, new_types.LayerPixels), **k)  # Embree builds, texture preparation
            old.run(*made_again(a, old_types.LayerPixels), **k)
            times = {"new": [], "old": []}
            for _ in range(args.repeats):
                for name, stage, types in (("new", new, new_types), ("old", old, old_types)):
                    start = time.perf_counter()
                    result = stage.run(*made_again(a, types.LayerPixels), **k)
                    times[name].append((time.perf_counter() - start) * 1000.0)
                    if name == "new":
                        new_result = result
                    else:
                        old_result = result
            ratio = statistics.median(times["new"]) / statistics.median(times["old"])
            print(f"  {mix:>32} {rays:7d} rays: {statistics.median(times['new']):7.1f} / "
                  f"{statistics.median(times['old']):7.1f} ms = {ratio:.2f}x, "
                  f"{verdict(same(new_result, old_result, args.rate is not None and args.rate < 1.0))}")
    finally:
        new.close(), old.close()


if __name__ == "__main__":
    main()
