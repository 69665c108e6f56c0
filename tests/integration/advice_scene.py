"""The tagging advisor's hand-built scene (tests/integration/test_advise.py).

A mirror cube facing a bright wall behind the camera (tagged for reflections), a matte cube
tagged for reflections (tracing changes nothing), an untagged chrome sphere facing the same
wall, and a glass ball tagged for refractions and shadows in front of a lit backdrop, with the
sun straight above and no floor: its shadow falls on nothing.  The camera slides 0.2 units over
frames 1-4."""
import numpy as np

from phrt.sample_scenes import showcase as build


def advice_scene(width=96, height=72):
    scene = build.empty_scene(width, height)
    build.mesh_object("BrightWall", build.plane(12.0), build.principled(
        "Bright", color=(1, 1, 1), roughness=0.9, emission=((1.0, 0.9, 0.3), 4.0)),
        location=(0.0, -3.0, 1.5), rotation=(np.radians(90), 0, 0))
    build.mesh_object("Backdrop", build.plane(14.0), build.principled(
        "Backdrop", color=(0.2, 0.4, 0.9), roughness=0.9, emission=((0.2, 0.5, 1.0), 1.5)),
        location=(0.0, 10.0, 1.5), rotation=(np.radians(90), 0, 0))
    mirror = build.mesh_object("Mirror", build.cube(1.0), build.principled(
        "MirrorMat", color=(0.9, 0.9, 0.9), metallic=1.0, roughness=0.0), location=(-1.6, 5.0, 1.0))
    matte = build.mesh_object("MatteCube", build.cube(1.0), build.principled(
        "MatteMat", color=(0.7, 0.7, 0.7), roughness=0.9), location=(0.0, 5.0, 0.4))
    build.mesh_object("ChromeSphere", build.sphere(0.6), build.principled(
        "Chrome", color=(0.95, 0.95, 0.95), metallic=1.0, roughness=0.05), location=(1.6, 5.0, 1.0))
    glass = build.mesh_object("GlassBall", build.sphere(0.5), build.principled(
        "Glass", color=(1, 1, 1), roughness=0.0, transmission=1.0, ior=1.45), location=(0.0, 4.5, 2.2))
    build.tag(mirror, shadows=False, reflections=True, refractions=False)
    build.tag(matte, shadows=False, reflections=True, refractions=False)
    build.tag(glass, shadows=True, reflections=False, refractions=True)
    build.add_light("SUN", (0.0, 0.0, 10.0), 3.0)
    camera = build.add_camera((0.0, 0.0, 1.5), (0.0, 5.0, 1.3), lens=30.0)
    camera.keyframe_insert("location", frame=1)
    camera.location.x += 0.2
    camera.keyframe_insert("location", frame=4)
    scene.frame_start, scene.frame_end = 1, 4
    scene.phrt.mode = "HYBRID"
    return scene, camera
