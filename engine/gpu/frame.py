"""``GPUFrame``: the raster half of one frame on the GPU, the core's ``RasterFrame``
(``phrt_addon/frame_types.py``).  It runs the passes in order and holds what they share; each
pass is its own module:

1. ``draw()``: the G-buffer layers, chunks outside the view culled, and the resolve with its
   read-back (``gbuffer``); the shadow maps that are missing (``shadow_maps``);
2. ``gbuffer()``: the full layers read back (``readback``), only when rays will be traced;
3. ``shade(traced)``: the tracer's results uploaded (``traced_textures``), the lighting passes
   (``lighting``, lights packed by ``light_struct``), the composite and one read-back of the
   final image (``composite``).

Runs inside ``RenderEngine.render()`` (``bl_use_gpu_context = True`` gives a GPU context, even
in background mode, where llvmpipe serves it on the CPU) or ``view_draw()``; what outlives the
frame belongs to ``resources.GPUResources``.
"""
from __future__ import annotations

import time

from ...phrt_addon.scene import shading
from ...phrt_addon.raster.gbuffer import GBuffer
from ...phrt_addon.scene.snapshot import SceneSnapshot
from .. import session
from . import composite, gbuffer, lighting, readback, shadow_maps, traced_textures
from .resources import GPUResources, gpu_module

# The shaders every frame binds, by name (the lighting variants depend on the frame's lights).
BUILDERS = {**gbuffer.BUILDERS, **composite.BUILDERS, shadow_maps.SHADER: shadow_maps.build}


def _ms(start):
    return (time.perf_counter() - start) * 1000.0


class GPUFrame:
    """The GPU work of one frame. ``draw()`` first; then the core calls ``gbuffer()`` if it
    traces and ``shade()`` once."""

    def __init__(self, snapshot: SceneSnapshot, resources: GPUResources | None = None):
        self.snapshot = snapshot
        self.resources = resources if resources is not None else session.current().resources
        self.width, self.height = snapshot.camera.width, snapshot.camera.height
        self.materials = shading.MaterialTable(snapshot.materials)
        self.raster_ms = 0.0
        self.setup_ms = 0.0
        self.stats = {}
        self.read_combined = True  # False: shade() leaves the image on the GPU (the viewport draws it)
        self.shaders = {}  # name -> shader, for this frame's passes
        self.fused = False  # all lights in one pass, which also composites the opaque layer
        self.transparent_drawn = False
        self.faces = False  # the G-buffer pass also wrote the face normals (gbuffer.draws_faces)
        self.measure = False  # shade() also writes what the traced terms changed
        self.traced_flags = (0.0, 0.0, 0.0)
        self._gbuffer = None
        self._gbuffer_rect = None  # the rectangle of the kept read-back (None: whole)

    # -- protocol --------------------------------------------------------------
    def draw(self):
        """G-buffer, resolve and its read-back, shadow maps; sets raster_ms and setup_ms."""
        if len(self.snapshot.elements) > gbuffer.MAX_ELEMENTS:
            raise ValueError(f"{len(self.snapshot.elements)} ray tracing elements: the G-buffer tells at most "
                             f"{gbuffer.MAX_ELEMENTS} apart; tag fewer objects or materials")
        if len(self.snapshot.materials) > gbuffer.MAX_MATERIALS:
            raise ValueError(f"{len(self.snapshot.materials)} materials: the G-buffer tells at most "
                             f"{gbuffer.MAX_MATERIALS} apart")
        gpu = gpu_module()
        resources = self.resources
        start = time.perf_counter()
        created_before = resources.uploads + sum(resources.created[kind] for kind in ("shader", "target"))
        setup_start = time.perf_counter()
        self.faces = gbuffer.draws_faces(self.snapshot)
        unused = gbuffer.unused_shaders(self.faces)
        self.shaders = {name: resources.shader(name, build) for name, build in BUILDERS.items() if name not in unused}
        counts = lighting.light_counts(len(self.snapshot.lights))
        # All lights in one pass: that pass also composites the opaque layer (one full-screen
        # pass less), if the implementation has the sampler it needs.
        self.fused = len(counts) == 1 and (lighting.lighting_samplers(counts[0], with_composite=True)
                                           <= resources.max_fragment_samplers())
        self.targets = resources.targets(self.width, self.height)
        self.material_table = resources.material_table(self.materials)
        self.draw_list = []  # (mesh, its groups, its chunks' boxes) of every mesh drawn
        keys = set()
        for mesh in self.snapshot.meshes:
            if mesh.n_triangles == 0:
                continue
            keys.add(mesh.geometry_key)
            _, groups, boxes = resources.mesh_batches(mesh)
            self.draw_list.append((mesh, groups, boxes))
        resources.retain_meshes(keys)
        self.material_textures = {}  # material index -> texture, for materials with an image
        for index, material in enumerate(self.snapshot.materials):
            texture = resources.material_texture(material)
            if texture is not None:
                self.material_textures[index] = texture
        created_after = resources.uploads + sum(resources.created[kind] for kind in ("shader", "target"))
        setup_ms = _ms(setup_start) if created_after > created_before else 0.0
        self.atlases, shadow_ms = shadow_maps.ensure(gpu, self)
        setup_ms += shadow_ms
        # The lighting variants need the shadow maps' kinds (cube or single view per light slot).
        created_before = resources.created["shader"]
        setup_start = time.perf_counter()
        self.lighting_names = []  # once per frame: shade() uses them
        for name, build in lighting.shaders(self.snapshot.lights, self.atlases, self.fused):
            self.shaders[name] = resources.shader(name, build)
            self.lighting_names.append(name)
        if resources.created["shader"] > created_before:
            setup_ms += _ms(setup_start)
        self.transparent_drawn = gbuffer.draw(gpu, self)
        resources.frames_drawn += 1
        self.view_depth, self.front_normal, self.front_element = gbuffer.resolve(gpu, self)
        self.setup_ms = setup_ms
        self.raster_ms = _ms(start)
        self.stats["gbuffer_ms"] = self.raster_ms - setup_ms

    def gbuffer(self, rect=None) -> GBuffer:
        """Both layers read back (float32 positions relative to the camera); with ``rect`` (x, y,
        w, h) only that rectangle, the other pixels cleared.  A read-back is kept for the frame:
        a whole one serves any later call, a rectangle the same rectangle."""
        if self._gbuffer is None or (self._gbuffer_rect is not None and rect != self._gbuffer_rect):
            self._gbuffer = readback.read_gbuffer(gpu_module(), self, self.transparent_drawn, rect, self.faces)
            self._gbuffer_rect = rect
        return self._gbuffer

    def traced_change(self):
        """(h, w, 4) of the last ``shade(..., measure_change=True)``: x the luminance of what traced
        reflections and refractions changed, y what traced shadows changed (clipped to [0, 1]).
        Every traced pixel lies in the rectangle the layers were read back in: only it is read back
        (zeros elsewhere); all of it when the layers were read whole."""
        rect = self._gbuffer_rect if self._gbuffer is not None else None
        return readback.read_target(gpu_module(), self, "traced_change", rect=rect)

    def read_albedo(self):
        """(opaque, transparent) albedo + metallic, (h, w, 4): only the reference lighting needs them."""
        return readback.read_albedo(gpu_module(), self)

    def read_shadow_maps(self) -> dict:
        """The shadow maps as numpy ``ShadowMap``s (the reference lighting and tests only)."""
        return shadow_maps.read(gpu_module(), self.atlases)

    def shade(self, traced, measure_change: bool = False):
        """Deferred lighting and composite with the tracer's results; returns Combined (h, w, 4),
        or None when ``read_combined`` is off (the frame target "combined" holds it).
        ``measure_change``: also write what the traced terms changed (``traced_change``)."""
        gpu = gpu_module()
        start = time.perf_counter()
        uploads = traced_textures.upload(gpu, self.resources, traced, self.width, self.height)
        self.stats["traced_upload_ms"] = _ms(start)
        self.measure = bool(measure_change)
        # A driver compiles a shader for each pipeline state on its first draw (llvmpipe JITs the
        # fragment code then): the first frame of a configuration pays it once, as set-up.
        configuration = (tuple(self.lighting_names), self.transparent_drawn, self.measure)
        first_use = self.resources.first_use("shade", configuration)
        self.traced_flags = traced_textures.flags(uploads)
        lighting.light(gpu, self, uploads)
        combined = composite.composite(gpu, self, uploads)
        # shade_ms: the upload of the traced results, the lighting and composite passes, the read-back.
        self.stats["shade_ms"] = _ms(start)
        self.stats["shade_setup_ms"] = self.stats["shade_ms"] - self.stats["traced_upload_ms"] if first_use else 0.0
        return combined
