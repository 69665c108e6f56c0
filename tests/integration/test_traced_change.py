"""The traced change the BENEFIT selection learns from (``GPUFrame.shade(..., measure_change=True)``).

A measured frame clears only the targets a first pass adds to (the transparent layer's light;
the opaque layer's first pass writes every pixel unblended, its change included): what one
frame measured must not leak into the next, and measuring must not change the image.  Run with
all lights in one fused pass and with two passes of lights (the second one blended)."""
import os
import tempfile

os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp(prefix="phrt-test-user-"))

import numpy as np  # noqa: E402
import pytest  # noqa: E402

pytest.importorskip("bpy")

from phrt.engine import extract  # noqa: E402
from phrt.engine.gpu import lighting, readback  # noqa: E402
from phrt.engine.gpu.frame import GPUFrame  # noqa: E402
from phrt.phrt_addon.frame_types import TracedTerms  # noqa: E402

from gpu_probe import run_on_gpu  # noqa: E402
from test_gpu_frame import lit_scene  # noqa: E402

pytestmark = pytest.mark.usefixtures("fresh_caches")


def traced_terms(gbuffer, seed, light):
    """Traced shadows of ``light`` (all in shadow) on a random quarter of each layer's pixels and
    a traced reflection on some opaque ones."""
    rng = np.random.default_rng(seed)
    traced = TracedTerms()
    for name in ("opaque", "transparent"):
        covered = np.flatnonzero(getattr(gbuffer, name).covered.ravel())
        chosen = np.sort(rng.choice(covered, size=len(covered) // 4, replace=False))
        traced.shadow_visibility[(name, light)] = (chosen, np.zeros(len(chosen), np.float32))
        if name == "opaque":
            traced.reflection["opaque"] = (chosen[:500], np.tile([[1.5, 0.1, 0.1]], (500, 1)))
    return traced


@pytest.mark.parametrize("extra_lights", [0, lighting.LIGHTS_PER_PASS - 4])
def test_a_measured_change_is_this_frames_alone_and_leaves_the_image_as_it_is(extra_lights):
    scene = lit_scene(extra_lights)

    def job(engine, depsgraph):
        snapshot = extract.extract(depsgraph)
        shaded = []
        for seed, light, measure in ((1, 1, True), (2, 2, True), (1, 1, False), (1, 1, True)):
            frame = GPUFrame(snapshot)
            frame.draw()
            gbuffer = frame.gbuffer()
            passes = (frame.fused, len(lighting.light_counts(len(snapshot.lights))))
            image = frame.shade(traced_terms(gbuffer, seed, light), measure_change=measure)
            shaded.append((np.array(image), np.array(frame.traced_change()) if measure else None, passes,
                           gbuffer.transparent.covered))
        return shaded

    (first, first_change, passes, transparent), (other, other_change, _, _), (unmeasured, _, _, _), \
        (again, again_change, _, _) = run_on_gpu(scene, job)
    assert passes == ((True, 1) if extra_lights == 0 else (False, 2))
    assert transparent.any()
    # Both layers' traced shadows are measured (the transparent layer's pass adds to the opaque's).
    shadow = first_change[..., 1].reshape(transparent.shape)  # both read back in GL row order
    assert shadow[transparent].max() > 0.01 and shadow[~transparent].max() > 0.01
    assert first_change[..., 0].max() > 0.005  # the traced reflection (through a dielectric's Fresnel)
    assert not np.allclose(first_change, other_change)
    # Nothing of the frame between leaks into the same frame measured again.
    np.testing.assert_allclose(again_change, first_change, rtol=1e-6, atol=1e-7)
    # Measuring does not change the image.
    np.testing.assert_allclose(first, unmeasured, rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(again, unmeasured, rtol=1e-6, atol=1e-7)


def test_after_a_cropped_read_back_the_change_is_read_in_that_rectangle_only():
    """A frame whose layers were read back in a rectangle (every traced pixel is in it) reads the
    change there and gives zeros elsewhere: inside, what a whole read gives."""
    scene = lit_scene(0)

    def job(engine, depsgraph):
        snapshot = extract.extract(depsgraph)
        out = []
        for rect in (None, (7, 5, 40, 30)):
            frame = GPUFrame(snapshot)
            frame.draw()
            gbuffer = frame.gbuffer(rect)
            traced = TracedTerms()
            for name in ("opaque", "transparent"):  # every covered pixel in the rectangle, in shadow
                covered = getattr(gbuffer, name).covered.copy()
                covered[:5], covered[35:], covered[:, :7], covered[:, 47:] = False, False, False, False
                pixels = np.flatnonzero(covered)
                traced.shadow_visibility[(name, 1)] = (pixels, np.zeros(len(pixels), np.float32))
            frame.shade(traced, measure_change=True)
            asked = []
            read = readback.read
            # read(gpu, framebuffer, slot, kind, channels, width, height, rect=None): the rectangle asked
            readback.read = lambda *args, **kwargs: asked.append(
                kwargs["rect"] if "rect" in kwargs else (args[7] if len(args) > 7 else None)) or read(*args, **kwargs)
            try:
                out.append(np.array(frame.traced_change()))
            finally:
                readback.read = read
            assert asked == [rect]  # only the rectangle read back
        return out

    whole, cropped = run_on_gpu(scene, job)
    inside = np.zeros(whole.shape[:2], bool)
    inside[5:35, 7:47] = True  # rows from the bottom, as read back
    assert whole[inside][..., 1].max() > 0.01
    np.testing.assert_allclose(cropped[inside], whole[inside], rtol=1e-6, atol=1e-7)
    assert not cropped[~inside].any()
