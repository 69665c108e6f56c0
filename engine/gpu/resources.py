"""The one owner of PHRT's GPU resources, kept across ``render()`` calls.

GPU objects created in one ``render()`` are valid in later ones (docs/platform-notes.md,
"GPU module in background mode"), so what a frame needs is created once and kept
while it stays valid:

- shaders: built on first use by the pass that names them, kept for the process;
- meshes: a vertex buffer (corners with the same vertex, normal and texture
  coordinate share a vertex) and per (material, element) group a batch per spatial
  chunk with its bounding box, culled against each frame's view (``draw_chunks``);
  keyed by the mesh's content (``MeshInstance.geometry_key``): a moved object
  keeps its batches (its transform is a push constant), an edited mesh gets new ones
  and its old ones are dropped at the end of the frame (``retain_meshes``);
- material textures, keyed by image and size; the material table (a small float
  texture), keyed by its content;
- shadow maps (``shadow_maps.ShadowAtlas``), keyed by their light and the geometry they see: a
  moved light re-renders only its own map;
- the frame's render targets, keyed by resolution.

Framebuffers are created per ``render()`` (they are not shared between contexts in a
UI session).  Nothing is freed in ``__del__``: ``release()`` drops every reference
deliberately, at the end of a replay, on file load and on unregister.

``counts()`` reports how many of each kind were created and freed and ``uploads`` how
often scene data was sent, so tests can check that a static replay creates and uploads
nothing after its first frame and frees what it created.
"""
from __future__ import annotations

import hashlib
from collections import Counter

import numpy as np

from ...phrt_addon.raster import draw_chunks
from ...phrt_addon.scene import rules
from .surface_glsl import MATERIAL_TABLE_WIDTH


def gpu_module():
    import gpu  # only inside render()/view_draw(): drawing is unavailable at module level in background mode
    return gpu


class GPUResources:
    def __init__(self):
        self._shaders = {}
        self._meshes = {}  # geometry key -> mesh_batches()
        self._textures = {}  # texture key -> GPUTexture
        self._material_table = (None, None)  # (content key, GPUTexture)
        self._shadows = {}  # shadow key -> ShadowAtlas
        self._targets = {}  # (width, height) -> {name: GPUTexture}
        self._constants = {}  # small fixed objects: fullscreen quad, placeholder textures
        self._max_fragment_samplers = None  # a property of the GL implementation
        self.created = Counter()
        self.freed = Counter()
        self.uploads = 0  # scene data sent to the GPU (meshes, textures, material tables)
        self.frames_drawn = 0  # G-buffers drawn into the targets (the viewport checks its image is current)
        self._states_drawn = set()  # pipeline states drawn once with the current shaders (first_use)

    # -- bookkeeping -------------------------------------------------------
    def counts(self) -> dict:
        """{kind: (created, freed)} since this owner was made."""
        kinds = set(self.created) | set(self.freed)
        return {kind: (self.created[kind], self.freed[kind]) for kind in sorted(kinds)}

    def live(self) -> dict:
        return {kind: created - freed for kind, (created, freed) in self.counts().items()}

    def release(self, keep_shaders: bool = False):
        """Drop every GPU object (file load, unregister), or everything that belongs to a scene
        (``keep_shaders``: the end of a replay; shaders depend on no scene and compiling them
        again costs a first draw of 0.3-0.6 s on llvmpipe)."""
        if not keep_shaders:
            self.freed["shader"] += len(self._shaders)
            self._shaders.clear()
            self._states_drawn.clear()
            self.freed["constant"] += len(self._constants)
            self._constants.clear()
        self.freed["mesh"] += len(self._meshes)
        self.freed["texture"] += len(self._textures)
        self.freed["material_table"] += self._material_table[1] is not None
        self.freed["shadow_map"] += len(self._shadows)
        self.freed["target"] += sum(len(targets) for targets in self._targets.values())
        self._meshes.clear()
        self._textures.clear()
        self._material_table = (None, None)
        self._shadows.clear()
        self._targets.clear()

    @property
    def empty(self) -> bool:
        return not (self._shaders or self._meshes or self._textures or self._shadows or self._targets
                    or self._constants or self._material_table[1] is not None)

    def max_fragment_samplers(self) -> int:
        """Textures a fragment shader may sample here (16 at least in any GL)."""
        if self._max_fragment_samplers is None:
            self._max_fragment_samplers = int(gpu_module().capabilities.max_textures_frag_get())
        return self._max_fragment_samplers

    def first_use(self, kind: str, state) -> bool:
        """True the first time ``state`` (hashable) of ``kind`` is drawn with these shaders."""
        key = (kind, state)
        if key in self._states_drawn:
            return False
        self._states_drawn.add(key)
        return True

    # -- shaders -------------------------------------------------------------
    def shader(self, name: str, build):
        """The shader called ``name``: ``build(gpu)`` (a pass's builder) makes it on first use.
        A name stands for one source: a variant's name says what its builder compiles in."""
        shader = self._shaders.get(name)
        if shader is None:
            shader = self._shaders[name] = build(gpu_module())
            self.created["shader"] += 1
        return shader

    def fullscreen_batch(self, shader):
        """Two triangles covering the viewport (one per shader: batches bind to a program)."""
        key = ("quad", id(shader))
        batch = self._constants.get(key)
        if batch is None:
            gpu = gpu_module()
            fmt = gpu.types.GPUVertFormat()
            fmt.attr_add(id="pos", comp_type="F32", len=2, fetch_mode="FLOAT")
            vbo = gpu.types.GPUVertBuf(fmt, 6)
            vbo.attr_fill("pos", [(-1, -1), (1, -1), (1, 1), (-1, -1), (1, 1), (-1, 1)])
            batch = self._constants[key] = gpu.types.GPUBatch(type="TRIS", buf=vbo)
            self.created["constant"] += 1
        return batch

    def placeholder(self, value: float):
        """A 1x1 RGBA32F texture of ``value`` bound where a pass has nothing to read."""
        key = ("placeholder", float(value))
        texture = self._constants.get(key)
        if texture is None:
            gpu = gpu_module()
            texture = self._constants[key] = gpu.types.GPUTexture(
                (1, 1), format="RGBA32F", data=gpu.types.Buffer("FLOAT", 4, [float(value)] * 4))
            self.created["constant"] += 1
        return texture

    # -- meshes --------------------------------------------------------------
    def mesh_batches(self, mesh):
        """(vertex buffer, [(material, element, [batch per chunk], (chunks, 2, 3) local boxes)],
        all the chunks' boxes in that order) of a mesh, uploaded on first use: vertices
        shared between corners, each (material, element) group cut into spatial chunks that
        a frame culls against its view (``draw_chunks``)."""
        entry = self._meshes.get(mesh.geometry_key)
        if entry is None:
            gpu = gpu_module()
            corners = mesh.triangles.reshape(-1)
            uvs = rules.texture_coordinates(mesh.corner_uvs, len(corners))
            vertex_of_corner, first_corner = draw_chunks.shared_vertices(corners, mesh.corner_normals, uvs)
            fmt = gpu.types.GPUVertFormat()
            fmt.attr_add(id="pos", comp_type="F32", len=3, fetch_mode="FLOAT")
            fmt.attr_add(id="nor", comp_type="F32", len=3, fetch_mode="FLOAT")
            fmt.attr_add(id="uv", comp_type="F32", len=2, fetch_mode="FLOAT")
            vbo = gpu.types.GPUVertBuf(fmt, len(first_corner))
            vbo.attr_fill("pos", np.ascontiguousarray(mesh.positions[corners[first_corner]], dtype=np.float32))
            vbo.attr_fill("nor", np.ascontiguousarray(mesh.corner_normals[first_corner], dtype=np.float32))
            vbo.attr_fill("uv", np.ascontiguousarray(uvs[first_corner], dtype=np.float32))
            corner_vertices = vertex_of_corner.reshape(-1, 3)
            groups = []
            for material, element, triangles in mesh.material_groups():
                batches, boxes = [], []
                for part, box in draw_chunks.chunks(mesh.positions, mesh.triangles, triangles):
                    ibo = gpu.types.GPUIndexBuf(type="TRIS", seq=np.ascontiguousarray(corner_vertices[part], np.int32))
                    batches.append(gpu.types.GPUBatch(type="TRIS", buf=vbo, elem=ibo))
                    boxes.append(box)
                groups.append((int(material), int(element), batches, np.asarray(boxes, np.float64)))
            boxes = np.concatenate([group[3] for group in groups]) if groups else np.zeros((0, 2, 3))
            entry = self._meshes[mesh.geometry_key] = (vbo, groups, boxes)
            self.created["mesh"] += 1
            self.uploads += 1
        return entry

    def retain_meshes(self, keys):
        """Drop the batches of meshes no longer drawn (an edited mesh's old content)."""
        for key in [key for key in self._meshes if key not in keys]:
            del self._meshes[key]
            self.freed["mesh"] += 1

    # -- textures ------------------------------------------------------------
    def material_texture(self, material):
        if material.texture is None:
            return None
        image = material.texture
        key = (material.texture_key or material.name, image.shape)
        texture = self._textures.get(key)
        if texture is None:
            gpu = gpu_module()
            image = rules.prepare_texture(image)  # what the tracer samples too
            height, width = image.shape[:2]
            buffer = gpu.types.Buffer("FLOAT", width * height * 4, image.ravel())
            texture = self._textures[key] = gpu.types.GPUTexture((width, height), format="RGBA32F", data=buffer)
            self.created["texture"] += 1
            self.uploads += 1
        return texture

    def material_table(self, table):
        """The per-material optical terms the lighting passes read (shading.MaterialTable), laid
        out as ``surface_glsl.material_row`` reads them."""
        count = len(table.ior)
        width = min(count, MATERIAL_TABLE_WIDTH)
        bands = -(-count // MATERIAL_TABLE_WIDTH)
        texels = np.zeros((bands * 2, width, 4), np.float32)
        index = np.arange(count)
        column, band = index % MATERIAL_TABLE_WIDTH, index // MATERIAL_TABLE_WIDTH
        texels[band * 2, column, 0] = table.transmission
        texels[band * 2, column, 1] = table.ior
        texels[band * 2, column, 2] = table.alpha
        texels[band * 2 + 1, column, :3] = table.emission
        key = hashlib.blake2b(texels.tobytes(), digest_size=16).hexdigest()
        if self._material_table[0] != key:
            gpu = gpu_module()
            buffer = gpu.types.Buffer("FLOAT", texels.size, texels.ravel())
            if self._material_table[1] is not None:
                self.freed["material_table"] += 1
            self._material_table = (key, gpu.types.GPUTexture((width, bands * 2), format="RGBA32F", data=buffer))
            self.created["material_table"] += 1
            self.uploads += 1
        return self._material_table[1]

    # -- shadow maps ---------------------------------------------------------
    def shadow_atlas(self, key):
        return self._shadows.get(key)

    def put_shadow_atlas(self, key, atlas):
        if key in self._shadows:
            self.freed["shadow_map"] += 1
        self._shadows[key] = atlas
        self.created["shadow_map"] += 1

    def retain_shadows(self, keys):
        """Drop maps of lights that moved or geometry that changed (a dragged light must not
        pile up maps)."""
        for key in [key for key in self._shadows if key not in keys]:
            del self._shadows[key]
            self.freed["shadow_map"] += 1

    # -- render targets ------------------------------------------------------
    TARGET_FORMATS = {
        "opaque_position": "RGBA32F", "opaque_normal": "RGBA32F", "opaque_albedo": "RGBA8",
        "opaque_element": "R32UI", "opaque_depth": "DEPTH_COMPONENT32F",
        "transparent_position": "RGBA32F", "transparent_normal": "RGBA32F", "transparent_albedo": "RGBA8",
        "transparent_element": "R32UI",
        # The face normal where secondary rays leave from (phrt_addon/raster/gbuffer.py
        # encode_face_normals): 8 bits a channel, a quarter of the read-back of RGBA32F, and an
        # offset direction needs no more.
        "opaque_geometric": "RGBA8", "transparent_geometric": "RGBA8",
        "transparent_mask": "DEPTH_COMPONENT32F",  # 0 where the transparent layer covers a pixel, else 1
        "normal_depth": "RGBA32F", "front_element": "R32UI",
        "opaque_light": "RGBA32F", "transparent_light": "RGBA32F", "combined": "RGBA32F",
        "shadow_change": "RGBA32F", "traced_change": "RGBA32F",  # the error-aware relevance only
        # Bound where a frame traced nothing: the size and format of the traced textures they
        # stand for (llvmpipe, like other drivers, compiles a shader variant per sampled texture
        # format and size class: a 1x1 stand-in would make every change of what is traced a new
        # variant, a 0.3-0.7 s JIT in the middle of a replay).
        "no_visibility": "R32F", "no_radiance": "RGBA32F",
    }
    # What the stand-ins hold: -1 (the shadow map stays), no traced radiance (alpha 0).
    TARGET_CLEAR = {"no_visibility": (-1.0,), "no_radiance": (0.0, 0.0, 0.0, 0.0)}

    def target(self, name: str, size) -> object | None:
        """One frame target at this resolution, if it exists (the viewport draws "combined")."""
        targets = self._targets.get((int(size[0]), int(size[1])))
        return None if targets is None else targets.get(name)

    def targets(self, width: int, height: int) -> dict:
        """The frame's textures at this resolution (kept; other resolutions are dropped)."""
        key = (int(width), int(height))
        targets = self._targets.get(key)
        if targets is None:
            gpu = gpu_module()
            for old in list(self._targets):
                self.freed["target"] += len(self._targets.pop(old))
            targets = self._targets[key] = {name: gpu.types.GPUTexture(key, format=fmt)
                                            for name, fmt in self.TARGET_FORMATS.items()}
            for name, value in self.TARGET_CLEAR.items():
                targets[name].clear(format="FLOAT", value=value)
            self.created["target"] += len(targets)
        return targets

