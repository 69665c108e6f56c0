"""Depsgraph -> ``SceneSnapshot``: the only place that reads Blender scene data for a frame.

Meshes are read with ``foreach_get`` into numpy arrays (never per-vertex Python
loops).  Triangulation, corner normals and UVs of an unchanged mesh are reused
from the session's mesh cache (``engine/session.py``, keyed by the evaluated mesh's name and a hash of its vertex
positions), so a replay converts each static mesh once.

A broken or unsupported object is reported in ``snapshot.problems`` and skipped
(or approximated); the frame still renders.  Never uses ``bpy.context``.
"""
from __future__ import annotations

import numpy as np

from .. import compat
from . import session
from ..phrt_addon import naming
from ..phrt_addon.scene import rules
from ..phrt_addon.report.metrics import srgb_to_linear
from ..phrt_addon.scene.snapshot import Camera, Element, Light, Material, MeshInstance, SceneSnapshot, Settings, geometry_key

GEOMETRY_TYPES = {"MESH", "CURVE", "SURFACE", "META", "FONT", "CURVES", "POINTCLOUD", "VOLUME", "GREASEPENCIL"}
MESH_CONVERTIBLE = {"MESH", "CURVE", "SURFACE", "META", "FONT"}
DEFAULT_MATERIAL = "__phrt_default__"


def instance_element_name(instance) -> str:
    """The element name of a depsgraph object instance (without material): ``phrt_addon/naming.py``."""
    if instance.is_instance:
        parent = instance.parent.name if instance.parent else "?"
        return naming.object_element(instance.object.name, parent, instance.persistent_id[0])
    return naming.object_element(instance.object.name)


def _read_mesh(mesh):
    """(positions (V,3) f32, triangles (T,3) i32, corner normals (3T,3) f32, corner uvs or None,
    triangle material slot (T,) i32, content key of positions and triangles) of a Blender mesh,
    cached by content."""
    n_vertices = len(mesh.vertices)
    positions = np.empty(n_vertices * 3, np.float32)
    mesh.vertices.foreach_get("co", positions)
    positions = positions.reshape(-1, 3)
    # The content key of positions equal to the ones this mesh had last time is not hashed again
    # (a comparison is ~10x cheaper than the hash); a changed mesh is hashed.
    shape_key = (mesh.name, n_vertices, len(mesh.polygons), len(mesh.loops))
    last = session.current().meshes.get(("positions",) + shape_key)
    if last is not None and np.array_equal(last[0], positions):
        positions_key = last[1]
    else:
        positions_key = geometry_key(positions)
        session.current().meshes.put(("positions",) + shape_key, (positions, positions_key))
    key = shape_key + (positions_key,)
    cached = session.current().meshes.get(key)
    if cached is not None:
        return cached
    mesh.calc_loop_triangles()
    n_triangles = len(mesh.loop_triangles)
    triangles = np.empty(n_triangles * 3, np.int32)
    mesh.loop_triangles.foreach_get("vertices", triangles)
    loops = np.empty(n_triangles * 3, np.int32)
    mesh.loop_triangles.foreach_get("loops", loops)
    slots = np.empty(n_triangles, np.int32)
    mesh.loop_triangles.foreach_get("material_index", slots)
    corner_normals_all = np.empty(len(mesh.loops) * 3, np.float32)
    mesh.corner_normals.foreach_get("vector", corner_normals_all)
    corner_normals = corner_normals_all.reshape(-1, 3)[loops]
    corner_uvs = None
    if mesh.uv_layers.active is not None and len(mesh.loops):
        uv_all = np.empty(len(mesh.loops) * 2, np.float32)
        mesh.uv_layers.active.uv.foreach_get("vector", uv_all)
        corner_uvs = rules.texture_coordinates(uv_all.reshape(-1, 2)[loops], len(loops))
    triangles = triangles.reshape(-1, 3)
    content_key = positions_key + geometry_key(triangles)
    value = (positions, triangles, np.ascontiguousarray(corner_normals), corner_uvs, slots, content_key)
    session.current().meshes.put(key, value)
    return value


def _image_pixels(image, problems):
    """Linear float32 (h, w, 4) pixels of an image, cached by name and size."""
    try:
        width, height = image.size
        key = (image.name, width, height, image.colorspace_settings.name)
        textures = session.current().textures
        if key in textures:
            return textures.get(key), "/".join(map(str, key))
        if width == 0 or height == 0:
            problems.append(f"Image '{image.name}' has no pixels; its texture is ignored")
            return None, None
        pixels = np.empty(width * height * 4, np.float32)
        image.pixels.foreach_get(pixels)
        pixels = pixels.reshape(height, width, 4)
        if not image.is_float and image.colorspace_settings.name.lower().startswith("srgb"):
            pixels[..., :3] = srgb_to_linear(pixels[..., :3])
        pixels = rules.prepare_texture(pixels)  # what raster and tracer both sample
        textures.put(key, pixels)
        return pixels, "/".join(map(str, key))
    except Exception as error:  # a missing file or a broken image must not stop the frame
        problems.append(f"Image '{getattr(image, 'name', '?')}' could not be read ({error}); its texture is ignored")
        return None, None


def _socket_value(node, name, default):
    socket = node.inputs.get(name)
    if socket is None:
        return default
    value = socket.default_value
    try:
        return tuple(value) if hasattr(value, "__len__") else float(value)
    except TypeError:
        return default


def read_material(material, problems) -> Material:
    """Principled BSDF parameters (approximating anything else by its viewport colour)."""
    if material is None:
        return Material(name=DEFAULT_MATERIAL)
    result = Material(
        name=material.name,
        base_color=tuple(material.diffuse_color[:3]),
        metallic=float(material.metallic),
        roughness=float(material.roughness),
    )
    tree = compat.node_tree_of(material)
    if tree is None:
        return result
    principled = next((node for node in tree.nodes if node.type == "BSDF_PRINCIPLED"), None)
    if principled is None:
        problems.append(f"Material '{material.name}' has no Principled BSDF; shaded with its viewport colour")
        return result
    result.base_color = tuple(_socket_value(principled, "Base Color", (0.8, 0.8, 0.8, 1.0))[:3])
    result.metallic = _socket_value(principled, "Metallic", 0.0)
    result.roughness = _socket_value(principled, "Roughness", 0.5)
    result.ior = _socket_value(principled, "IOR", 1.5)
    result.alpha = _socket_value(principled, "Alpha", 1.0)
    result.transmission = _socket_value(principled, "Transmission Weight", 0.0)
    emission = _socket_value(principled, "Emission Color", (0.0, 0.0, 0.0, 1.0))[:3]
    strength = _socket_value(principled, "Emission Strength", 0.0)
    result.emission = tuple(float(c) * strength for c in emission)
    base_input = principled.inputs.get("Base Color")
    if base_input is not None and base_input.is_linked:
        source = base_input.links[0].from_node
        if source.type == "TEX_IMAGE" and source.image is not None:
            result.texture, result.texture_key = _image_pixels(source.image, problems)
            result.base_color = (1.0, 1.0, 1.0)
        else:
            problems.append(f"Material '{material.name}': only an Image Texture is supported on Base Color; "
                            f"'{source.bl_idname}' is approximated by the socket's colour")
    return result


def _element_settings(owner):
    settings = getattr(owner, "phrt", None)
    return settings


def _make_element(name, object_name, material_name, settings, candidate):
    return Element(
        name=name, object_name=object_name, material_name=material_name, candidate=candidate,
        priority=float(settings.priority) if settings else 1.0,
        rt_cost=float(settings.rt_cost) if settings else 1.0,
        shadows=bool(settings.shadows) if settings else True,
        reflections=bool(settings.reflections) if settings else True,
        refractions=bool(settings.refractions) if settings else True,
    )


def read_settings(scene) -> Settings:
    props = getattr(scene, "phrt", None)
    if props is None:
        return Settings()
    return Settings(mode=props.mode, budget_ms=float(props.budget_ms), selection_weight=float(props.selection_weight),
                    max_area_fraction=float(props.max_area_fraction), max_bounces=int(props.max_bounces),
                    cost_mode=props.cost_mode, shadow_map_size=int(props.shadow_map_size),
                    budget_at=float(props.budget_at) if props.use_budget_at else None,
                    relevance=props.relevance, selection_order=props.selection_order,
                    selection=getattr(props, "selection", "PAPER"),
                    quality_tiers=bool(getattr(props, "quality_tiers", False)))


def resolution(scene):
    render = scene.render
    scale = render.resolution_percentage / 100.0
    return max(1, int(render.resolution_x * scale)), max(1, int(render.resolution_y * scale))


def read_camera(depsgraph, camera_object, width, height) -> Camera:
    scene = depsgraph.scene_eval
    camera_eval = camera_object.evaluated_get(depsgraph)
    render = scene.render
    projection = camera_eval.calc_matrix_camera(depsgraph, x=width, y=height,
                                                scale_x=render.pixel_aspect_x, scale_y=render.pixel_aspect_y)
    data = camera_eval.data
    return Camera(
        matrix_world=np.array(camera_eval.matrix_world, dtype=np.float64),
        projection=np.array(projection, dtype=np.float64),
        width=width, height=height,
        ortho=getattr(data, "type", "PERSP") == "ORTHO",
        clip_start=float(getattr(data, "clip_start", 0.1)),
        clip_end=float(getattr(data, "clip_end", 1000.0)),
    )


def read_light(obj) -> Light:
    data = obj.data
    matrix = np.array(obj.matrix_world, dtype=np.float64)
    direction = -matrix[:3, 2]
    norm = np.linalg.norm(direction)
    direction = direction / norm if norm > 0 else np.array([0.0, 0.0, -1.0])
    kind = data.type
    color = np.array(data.color[:3], dtype=np.float64) * float(data.energy)
    return Light(
        name=obj.name, kind=kind, color=tuple(color), position=tuple(matrix[:3, 3]), direction=tuple(direction),
        spot_size=float(getattr(data, "spot_size", np.pi / 4)), spot_blend=float(getattr(data, "spot_blend", 0.15)),
        radius=float(getattr(data, "shadow_soft_size", 0.0)), cast_shadows=bool(getattr(data, "use_shadow", True)),
    )


def extract(depsgraph, camera_override=None, settings_override=None) -> SceneSnapshot:
    """Build the frame's snapshot from an evaluated depsgraph."""
    scene = depsgraph.scene_eval
    problems = []
    width, height = resolution(scene)
    camera_object = camera_override or scene.camera
    if camera_object is None:
        raise ValueError("The scene has no active camera: add a camera and make it active (Ctrl+Numpad 0)")
    camera = read_camera(depsgraph, camera_object, width, height)

    materials = [Material(name=DEFAULT_MATERIAL)]
    material_index = {DEFAULT_MATERIAL: 0}
    elements = []
    element_index = {}
    meshes = []
    lights = []
    warned_types = set()

    def material_slot_index(material):
        name = material.name if material is not None else DEFAULT_MATERIAL
        if name not in material_index:
            material_index[name] = len(materials)
            materials.append(read_material(material, problems))
        return material_index[name]

    def element_for(name, object_name, material_name, settings, candidate):
        if name not in element_index:
            element_index[name] = len(elements)
            elements.append(_make_element(name, object_name, material_name, settings, candidate))
        return element_index[name]

    for instance in depsgraph.object_instances:
        obj = instance.object
        try:
            if obj.type == "LIGHT":
                lights.append(read_light(obj))
                continue
            if obj.type not in MESH_CONVERTIBLE:
                if obj.type in GEOMETRY_TYPES and obj.type not in warned_types:
                    warned_types.add(obj.type)
                    problems.append(f"Objects of type {obj.type} are not drawn by PHRT yet (e.g. '{obj.name}')")
                continue
            name = instance_element_name(instance)
            original = obj.original
            owned_mesh = obj.type != "MESH"
            mesh = obj.to_mesh() if owned_mesh else obj.data
            try:
                if mesh is None or len(mesh.polygons) == 0:
                    continue
                positions, triangles, corner_normals, corner_uvs, slots, content_key = _read_mesh(mesh)
                slot_materials = [slot.material for slot in obj.material_slots] or [None]
                slot_to_material = np.array([material_slot_index(m) for m in slot_materials], np.int32)
                slots = np.clip(slots, 0, len(slot_to_material) - 1)
                tri_material = slot_to_material[slots]
                tri_element = np.full(len(triangles), -1, np.int32)
                object_settings = _element_settings(original)
                # Material-tagged faces form their own element; the rest belong to the object's element.
                for slot_index, material in enumerate(slot_materials):
                    material_settings = _element_settings(material.original) if material is not None else None
                    if material_settings is not None and material_settings.candidate:
                        index = element_for(naming.material_element(name, material.name), original.name, material.name,
                                            material_settings, True)
                        tri_element[slots == slot_index] = index
                rest = tri_element < 0
                if np.any(rest):
                    candidate = bool(object_settings.candidate) if object_settings is not None else False
                    tri_element[rest] = element_for(name, original.name, None, object_settings, candidate)
                matrix = np.array(instance.matrix_world, dtype=np.float64)
                if not np.all(np.isfinite(matrix)) or not np.all(np.isfinite(positions)):
                    problems.append(f"Object '{name}' has non-finite coordinates and was skipped")
                    continue
                meshes.append(MeshInstance(
                    name=name, matrix_world=matrix, positions=positions, triangles=triangles,
                    corner_normals=corner_normals, corner_uvs=corner_uvs,
                    tri_material=tri_material, tri_element=tri_element,
                    # The content was hashed once when the mesh was read: only the per-object
                    # material and element assignment is hashed per frame.
                    geometry_key=geometry_key(np.frombuffer(content_key.encode(), np.uint8), tri_material,
                                              tri_element)))
            finally:
                if owned_mesh:
                    obj.to_mesh_clear()
        except Exception as error:  # one broken object must not stop the frame
            problems.append(f"Object '{getattr(obj, 'name', '?')}' skipped: {error}")

    world = scene.world
    world_color = (0.05, 0.05, 0.05)
    if world is not None:
        world_color = tuple(world.color[:3])
        tree = compat.node_tree_of(world)
        if tree is not None:
            background = next((n for n in tree.nodes if n.type == "BACKGROUND"), None)
            if background is not None:
                color = background.inputs["Color"].default_value
                strength = background.inputs["Strength"].default_value
                world_color = tuple(float(c) * float(strength) for c in color[:3])
    settings = settings_override or read_settings(scene)
    return SceneSnapshot(meshes=meshes, materials=materials, elements=elements, lights=lights, camera=camera,
                         world_color=world_color, settings=settings, frame=int(scene.frame_current),
                         problems=problems)
