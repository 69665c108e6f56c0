"""Turning numpy geometry, colours and camera tracks into Blender data.

The only module of the sample scenes that writes ``bpy.data``: meshes from
``geometry.MeshData`` (``foreach_set``, no operators), Principled BSDF
materials, packed images made from arrays, lights, the sky, camera objects
keyframed on every frame, and the PHRT tags of candidates.
"""
from __future__ import annotations

import math

import bpy
import numpy as np

from .. import compat
from .geometry import MeshData

# Edges whose faces meet at more than this angle are shaded sharp (the
# "auto smooth" look: round primitives smooth, boxes and arches crisp).
SMOOTH_ANGLE = math.radians(40.0)


def ensure_properties() -> None:
    """Register PHRT's PropertyGroups when the add-on is not registered.

    Only the properties (not the engine or the UI): the sample scenes need
    ``Object.phrt``, ``Material.phrt`` and ``Scene.phrt`` to store tags.
    """
    if not hasattr(bpy.types.Object, "phrt"):
        from .. import properties
        properties.register()


def reset_file() -> None:
    """Start from an empty file (no default cube, camera or light)."""
    bpy.ops.wm.read_homefile(use_empty=True)


class SceneData:
    """Materials and objects of one sample scene, linked into one scene."""

    def __init__(self, scene: bpy.types.Scene):
        self.scene = scene
        self.materials: dict[str, bpy.types.Material] = {}

    # ------------------------------------------------------------------ materials
    def material(self, name: str, base_color=(0.8, 0.8, 0.8), metallic: float = 0.0,
                 roughness: float = 0.5, transmission: float = 0.0, ior: float = 1.5,
                 image: bpy.types.Image | None = None, coat: float = 0.0,
                 sheen: float = 0.0) -> bpy.types.Material:
        """A Principled BSDF material (``image`` feeds Base Color through an
        Image Texture node on the UV map)."""
        if name in self.materials:
            return self.materials[name]
        mat = bpy.data.materials.new(name)
        nodes = compat.ensure_node_tree(mat).nodes
        bsdf = nodes.get("Principled BSDF")
        color = tuple(base_color) + (1.0,) * (4 - len(base_color))
        bsdf.inputs["Base Color"].default_value = color
        bsdf.inputs["Metallic"].default_value = metallic
        bsdf.inputs["Roughness"].default_value = roughness
        bsdf.inputs["IOR"].default_value = ior
        bsdf.inputs["Transmission Weight"].default_value = transmission
        bsdf.inputs["Coat Weight"].default_value = coat
        bsdf.inputs["Sheen Weight"].default_value = sheen
        mat.diffuse_color = color          # Workbench and the viewport's solid mode
        mat.metallic = metallic
        mat.roughness = roughness
        if image is not None:
            texture = nodes.new("ShaderNodeTexImage")
            texture.image = image
            texture.location = (-320.0, 260.0)
            mat.node_tree.links.new(texture.outputs["Color"], bsdf.inputs["Base Color"])
        self.materials[name] = mat
        return mat

    # ------------------------------------------------------------------ objects
    def mesh_object(self, name: str, data: MeshData, materials, location=(0.0, 0.0, 0.0),
                    smooth: bool = True) -> bpy.types.Object:
        """A mesh object built from ``data`` with ``materials`` in slot order."""
        verts, loops, sizes, poly_materials, uvs = data.arrays()
        mesh = bpy.data.meshes.new(name)
        mesh.vertices.add(len(verts))
        mesh.vertices.foreach_set("co", verts.astype(np.float32).reshape(-1))
        mesh.loops.add(len(loops))
        mesh.loops.foreach_set("vertex_index", loops)
        mesh.polygons.add(len(sizes))
        starts = np.zeros(len(sizes), dtype=np.int32)
        np.cumsum(sizes[:-1], out=starts[1:])
        mesh.polygons.foreach_set("loop_start", starts)
        mesh.polygons.foreach_set("material_index", poly_materials)
        if uvs is not None:
            layer = mesh.uv_layers.new(name="UVMap")
            layer.data.foreach_set("uv", uvs.reshape(-1))
        mesh.update(calc_edges=True)
        problems = mesh.validate(verbose=False)
        if problems:
            raise ValueError(f"mesh {name!r} had invalid geometry")
        if smooth:
            mesh.shade_smooth()
            mesh.set_sharp_from_angle(angle=SMOOTH_ANGLE)
        for mat in materials:
            mesh.materials.append(mat)
        obj = bpy.data.objects.new(name, mesh)
        obj.location = location
        self.scene.collection.objects.link(obj)
        return obj

    # ------------------------------------------------------------------ lights
    def light(self, name: str, kind: str, location, energy: float, color=(1.0, 1.0, 1.0),
              rotation=(0.0, 0.0, 0.0), size: float = 0.1, angle_deg: float = 0.5) -> bpy.types.Object:
        light = bpy.data.lights.new(name, kind)
        light.energy = energy
        light.color = color
        if kind == "SUN":
            light.angle = math.radians(angle_deg)
        elif kind == "AREA":
            light.size = size
        else:
            light.shadow_soft_size = size
        obj = bpy.data.objects.new(name, light)
        obj.location = location
        obj.rotation_euler = rotation
        self.scene.collection.objects.link(obj)
        return obj

    def sun_towards(self, name: str, elevation_deg: float, azimuth_deg: float, strength: float,
                    color=(1.0, 0.96, 0.9)) -> bpy.types.Object:
        """A sun shining from ``azimuth_deg`` (0 = from +X, 90 = from +Y) at
        ``elevation_deg`` above the horizon."""
        # A sun lamp shines along its local -Z: tilt it down from the zenith
        # by (90 - elevation) and turn it to face away from the azimuth.
        tilt = math.radians(90.0 - elevation_deg)
        turn = math.radians(azimuth_deg + 90.0)
        return self.light(name, "SUN", (0.0, 0.0, 30.0), strength, color, rotation=(tilt, 0.0, turn))

    def sky(self, name: str, color, strength: float) -> None:
        world = bpy.data.worlds.new(name)
        background = compat.ensure_node_tree(world).nodes.get("Background")
        background.inputs["Color"].default_value = tuple(color) + (1.0,)
        background.inputs["Strength"].default_value = strength
        world.color = color
        self.scene.world = world


# ---------------------------------------------------------------------- tags

def tag(owner, priority: float, shadows: bool = False, reflections: bool = False,
        refractions: bool = False, rt_cost: float = 1.0) -> None:
    """Make an object or a material a ray tracing candidate with the paper's
    priority K and cost multiplier Q, and the effects it gets."""
    settings = owner.phrt
    settings.candidate = True
    settings.priority = priority
    settings.shadows = shadows
    settings.reflections = reflections
    settings.refractions = refractions
    settings.rt_cost = rt_cost


# ---------------------------------------------------------------------- images

def packed_image(name: str, rgb: np.ndarray) -> bpy.types.Image:
    """A packed 8-bit image from an ``(H, W, 3)`` array of sRGB values in
    [0, 1] (row 0 is the bottom row, as Blender stores pixels)."""
    height, width = rgb.shape[:2]
    image = bpy.data.images.new(name, width, height, alpha=False)
    rgba = np.ones((height, width, 4), dtype=np.float32)
    rgba[..., :3] = np.clip(rgb, 0.0, 1.0)
    image.pixels.foreach_set(rgba.reshape(-1))
    image.pack()
    return image


# ---------------------------------------------------------------------- cameras

def camera_object(scene_data: SceneData, name: str, lens_mm: float, sensor_mm: float = 36.0):
    camera = bpy.data.cameras.new(name)
    camera.lens = lens_mm
    camera.sensor_width = sensor_mm
    camera.sensor_fit = "HORIZONTAL"
    camera.clip_start = 0.05
    camera.clip_end = 250.0
    obj = bpy.data.objects.new(name, camera)
    scene_data.scene.collection.objects.link(obj)
    return obj


def keyframe_every_frame(obj: bpy.types.Object, first_frame: int, locations: np.ndarray,
                         rotations: np.ndarray) -> None:
    """Key ``location`` and ``rotation_euler`` on every frame from
    ``first_frame`` (linear interpolation between keys one frame apart)."""
    obj.rotation_mode = "XYZ"
    obj.location = locations[0]
    obj.rotation_euler = rotations[0]
    action = bpy.data.actions.new(f"{obj.name}Action")
    slot = action.slots.new(id_type="OBJECT", name=obj.name)
    animation = obj.animation_data_create()
    animation.action = action
    animation.action_slot = slot
    channelbag = compat.ensure_channelbag(action, slot)
    frames = first_frame + np.arange(len(locations), dtype=np.float64)
    linear = bpy.types.Keyframe.bl_rna.properties["interpolation"].enum_items["LINEAR"].value
    for data_path, values in (("location", locations), ("rotation_euler", rotations)):
        for index in range(3):
            curve = compat.new_fcurve(channelbag, data_path, index, "Object Transforms")
            points = curve.keyframe_points
            points.add(len(frames))
            co = np.stack((frames, values[:, index]), axis=1).astype(np.float32)
            points.foreach_set("co", co.reshape(-1))
            points.foreach_set("interpolation", np.full(len(frames), linear, dtype=np.int32))
            curve.update()
