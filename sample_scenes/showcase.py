"""Small scenes built in code for the demo frame and the render tests.

``build_showcase()``: a floor, a red cube, a mirror sphere (candidate), a glass
slab (candidate), a thin fence (candidate shadow caster), a sun and a point
light, and a camera - every effect of the pipeline in one 100 ms frame.
Each builder starts from an empty file and returns the scene.
"""
from __future__ import annotations

import math

import bmesh
import bpy

from .. import compat


def empty_scene(width=320, height=240):
    bpy.ops.wm.read_homefile(use_empty=True)
    scene = bpy.context.scene
    scene.render.resolution_x = width
    scene.render.resolution_y = height
    scene.render.resolution_percentage = 100
    scene.frame_start = scene.frame_end = 1
    if scene.world is None:
        scene.world = bpy.data.worlds.new("World")
    scene.world.color = (0.05, 0.06, 0.08)
    scene.view_settings.view_transform = "Standard"
    try:
        scene.render.engine = "PHRT"
    except TypeError:
        pass
    return scene


def principled(name, color=(0.8, 0.8, 0.8), metallic=0.0, roughness=0.5, transmission=0.0, ior=1.45,
               alpha=1.0, emission=None):
    material = bpy.data.materials.new(name)
    bsdf = compat.ensure_node_tree(material).nodes.get("Principled BSDF")
    bsdf.inputs["Base Color"].default_value = (*color, 1.0)
    bsdf.inputs["Metallic"].default_value = metallic
    bsdf.inputs["Roughness"].default_value = roughness
    bsdf.inputs["Transmission Weight"].default_value = transmission
    bsdf.inputs["IOR"].default_value = ior
    bsdf.inputs["Alpha"].default_value = alpha
    if emission is not None:
        bsdf.inputs["Emission Color"].default_value = (*emission[0], 1.0)
        bsdf.inputs["Emission Strength"].default_value = emission[1]
    material.diffuse_color = (*color, 1.0)
    return material


def mesh_object(name, build, material=None, location=(0, 0, 0), rotation=(0, 0, 0), scale=(1, 1, 1),
                smooth=False):
    """An object whose mesh ``build(bm)`` fills with bmesh operators."""
    mesh = bpy.data.meshes.new(name)
    bm = bmesh.new()
    build(bm)
    bm.to_mesh(mesh)
    bm.free()
    if smooth:
        mesh.shade_smooth()
    obj = bpy.data.objects.new(name, mesh)
    obj.location = location
    obj.rotation_euler = rotation
    obj.scale = scale
    if material is not None:
        mesh.materials.append(material)
    bpy.context.scene.collection.objects.link(obj)
    return obj


def cube(size=1.0):
    return lambda bm: bmesh.ops.create_cube(bm, size=size)


def sphere(radius=1.0, segments=48, rings=24):
    return lambda bm: bmesh.ops.create_uvsphere(bm, u_segments=segments, v_segments=rings, radius=radius)


def plane(size=1.0):
    return lambda bm: bmesh.ops.create_grid(bm, x_segments=1, y_segments=1, size=size / 2.0)


def add_camera(location, target, lens=35.0, name="Camera"):
    camera = bpy.data.objects.new(name, bpy.data.cameras.new(name))
    camera.data.lens = lens
    camera.data.clip_start = 0.05
    camera.location = location
    direction = (target[0] - location[0], target[1] - location[1], target[2] - location[2])
    from mathutils import Vector
    camera.rotation_euler = Vector(direction).to_track_quat("-Z", "Y").to_euler()
    bpy.context.scene.collection.objects.link(camera)
    bpy.context.scene.camera = camera
    return camera


def add_light(kind, location, energy, rotation=(0, 0, 0), color=(1, 1, 1), name=None, **settings):
    data = bpy.data.lights.new(name or kind.title(), kind)
    data.energy = energy
    data.color = color
    for key, value in settings.items():
        setattr(data, key, value)
    obj = bpy.data.objects.new(name or kind.title(), data)
    obj.location = location
    obj.rotation_euler = rotation
    bpy.context.scene.collection.objects.link(obj)
    return obj


def tag(obj_or_material, **settings):
    props = obj_or_material.phrt
    props.candidate = True
    for key, value in settings.items():
        setattr(props, key, value)
    return obj_or_material


def build_showcase(width=320, height=240):
    scene = empty_scene(width, height)
    floor_material = principled("Floor", color=(0.6, 0.6, 0.55), roughness=0.8)
    mesh_object("Floor", plane(20.0), floor_material)
    mesh_object("RedCube", cube(1.0), principled("Red", color=(0.8, 0.05, 0.04), roughness=0.6),
                location=(-1.6, 1.2, 0.5))
    mirror = mesh_object("MirrorSphere", sphere(0.7), principled("Mirror", color=(0.9, 0.9, 0.9), metallic=1.0,
                                                                 roughness=0.02),
                         location=(0.2, 0.4, 0.7), smooth=True)
    tag(mirror, priority=2.0, shadows=True, reflections=True, refractions=False)
    glass = mesh_object("GlassSlab", cube(1.0), principled("Glass", color=(0.95, 0.97, 1.0), transmission=1.0,
                                                           roughness=0.0, ior=1.5),
                        location=(1.7, -0.3, 0.3), scale=(0.8, 0.8, 0.3))
    tag(glass, priority=1.0, shadows=False, reflections=True, refractions=True)
    fence_material = principled("Wood", color=(0.45, 0.3, 0.15), roughness=0.7)
    fence = mesh_object("Fence", _fence(), fence_material, location=(-0.2, -1.6, 0.0))
    tag(fence, priority=1.0, shadows=True, reflections=False, refractions=False)
    add_light("SUN", (0, 0, 5), 3.0, rotation=(math.radians(40), math.radians(10), math.radians(30)), name="Sun")
    add_light("POINT", (2.0, 2.5, 2.5), 300.0, color=(1.0, 0.85, 0.7), name="Lamp", shadow_soft_size=0.1)
    add_camera((4.5, -5.5, 3.2), (0.0, 0.2, 0.5))
    return scene


def _fence(posts=7, width=2.4, height=1.0, post=0.05):
    def build(bm):
        for index in range(posts):
            x = -width / 2 + index * width / (posts - 1)
            result = bmesh.ops.create_cube(bm, size=1.0)
            bmesh.ops.scale(bm, vec=(post, post, height), verts=result["verts"])
            bmesh.ops.translate(bm, vec=(x, 0, height / 2), verts=result["verts"])
        for z in (0.35, 0.8):
            result = bmesh.ops.create_cube(bm, size=1.0)
            bmesh.ops.scale(bm, vec=(width, post * 0.6, post * 1.5), verts=result["verts"])
            bmesh.ops.translate(bm, vec=(0, 0, z), verts=result["verts"])
    return build
