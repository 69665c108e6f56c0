"""First-person camera paths of the sample scenes, computed for every frame.

A path is what a level designer would block out for a play-test: waypoints
on the floor, the player's speed over time (walking ~1.4 m/s, running
~4.5 m/s), where the player looks (at a target, or glancing left/right/up),
all at eye height. ``track()`` turns that into one camera position, yaw and
pitch per frame: a centripetal Catmull-Rom curve through the waypoints,
walked at the smoothed speed, looking along the walking direction plus the
glances, blended towards look-at targets. Plain numpy, no bpy.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

FPS = 60
FRAMES = 1000
EYE_HEIGHT_M = 1.7
WALK_MPS = 1.4
RUN_MPS = 4.5
# Players look slightly down while moving.
DEFAULT_PITCH_DEG = -4.0


@dataclass(frozen=True)
class Look:
    """Look at ``target`` (x, y, z) from ``start`` to ``end`` (frames),
    turning the head towards it over ``ramp`` frames at both ends."""

    start: int
    end: int
    target: tuple
    ramp: int = 30


@dataclass(frozen=True)
class PathSpec:
    name: str
    description: str
    waypoints: tuple                 # (x, y) on the floor, in walking order
    speeds: tuple                    # (frame, m/s) keys, linear in between, then smoothed
    glances: tuple = ()              # (frame, yaw offset deg (+ = left), pitch deg) keys
    looks: tuple = field(default=())  # Look windows
    floor_z: float = 0.0


@dataclass
class Track:
    """Per-frame camera state: ``location`` (F, 3), ``yaw`` and ``pitch`` (F,)
    in radians; yaw 0 looks along +X, pi/2 along +Y."""

    location: np.ndarray
    yaw: np.ndarray
    pitch: np.ndarray

    def rotation_euler(self) -> np.ndarray:
        """Blender XYZ Euler angles of a camera (which looks down its -Z)."""
        return np.stack((math.pi / 2 + self.pitch, np.zeros_like(self.yaw), self.yaw - math.pi / 2), axis=1)


def gaussian_smooth(values: np.ndarray, sigma_frames: float) -> np.ndarray:
    """Gaussian low-pass along axis 0 with the ends held (no scipy in Blender)."""
    if sigma_frames <= 0:
        return values
    radius = int(math.ceil(3 * sigma_frames))
    kernel = np.exp(-0.5 * (np.arange(-radius, radius + 1) / sigma_frames) ** 2)
    kernel /= kernel.sum()
    padded = np.concatenate((np.repeat(values[:1], radius, axis=0), values,
                             np.repeat(values[-1:], radius, axis=0)))
    if values.ndim == 1:
        return np.convolve(padded, kernel, mode="valid")
    return np.stack([np.convolve(padded[:, i], kernel, mode="valid") for i in range(values.shape[1])], axis=1)


def catmull_rom(points: np.ndarray, samples_per_segment: int = 200) -> np.ndarray:
    """Dense centripetal Catmull-Rom curve through ``points`` (N, 2)."""
    points = np.asarray(points, dtype=np.float64)
    padded = np.concatenate((2 * points[:1] - points[1:2], points, 2 * points[-1:] - points[-2:-1]))
    out = []
    t = np.linspace(0.0, 1.0, samples_per_segment, endpoint=False)[:, None]
    for i in range(1, len(padded) - 2):
        p0, p1, p2, p3 = padded[i - 1], padded[i], padded[i + 1], padded[i + 2]
        t0 = 0.0
        t1 = t0 + np.linalg.norm(p1 - p0) ** 0.5
        t2 = t1 + np.linalg.norm(p2 - p1) ** 0.5
        t3 = t2 + np.linalg.norm(p3 - p2) ** 0.5
        u = t1 + t * (t2 - t1)
        a1 = (t1 - u) / (t1 - t0) * p0 + (u - t0) / (t1 - t0) * p1
        a2 = (t2 - u) / (t2 - t1) * p1 + (u - t1) / (t2 - t1) * p2
        a3 = (t3 - u) / (t3 - t2) * p2 + (u - t2) / (t3 - t2) * p3
        b1 = (t2 - u) / (t2 - t0) * a1 + (u - t0) / (t2 - t0) * a2
        b2 = (t3 - u) / (t3 - t1) * a2 + (u - t1) / (t3 - t1) * a3
        out.append((t2 - u) / (t2 - t1) * b1 + (u - t1) / (t2 - t1) * b2)
    out.append(points[-1:])
    return np.concatenate(out)


def _smoothstep(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def _eased_keys(frames: np.ndarray, keys, column: int) -> np.ndarray:
    """Interpolate key values with an ease-in-out between consecutive keys."""
    key_frames = np.array([k[0] for k in keys], dtype=np.float64)
    key_values = np.array([k[column] for k in keys], dtype=np.float64)
    index = np.clip(np.searchsorted(key_frames, frames, side="right") - 1, 0, len(keys) - 1)
    nxt = np.minimum(index + 1, len(keys) - 1)
    span = np.maximum(key_frames[nxt] - key_frames[index], 1e-9)
    w = _smoothstep((frames - key_frames[index]) / span)
    return key_values[index] + w * (key_values[nxt] - key_values[index])


def _wrap(angle: np.ndarray) -> np.ndarray:
    return (angle + math.pi) % (2 * math.pi) - math.pi


def track(spec: PathSpec, frames: int = FRAMES, fps: int = FPS) -> Track:
    """Where the camera of ``spec`` is and looks on each of ``frames`` frames."""
    curve = catmull_rom(np.array(spec.waypoints))
    steps = np.linalg.norm(np.diff(curve, axis=0), axis=1)
    arc = np.concatenate(([0.0], np.cumsum(steps)))
    length = float(arc[-1])

    frame = np.arange(1, frames + 1, dtype=np.float64)
    key_frames = [k[0] for k in spec.speeds]
    speed = np.interp(frame, key_frames, [k[1] for k in spec.speeds])
    speed = gaussian_smooth(speed, 10.0)
    distance = np.concatenate(([0.0], np.cumsum(speed[:-1]) / fps))
    if distance[-1] > length + 1e-6:
        raise ValueError(f"{spec.name}: the speeds cover {distance[-1]:.1f} m but the waypoints "
                         f"only {length:.1f} m; add waypoints or slow down")
    x = np.interp(distance, arc, curve[:, 0])
    y = np.interp(distance, arc, curve[:, 1])
    location = np.stack((x, y, np.full_like(x, spec.floor_z + EYE_HEIGHT_M)), axis=1)

    tangent = np.gradient(curve, axis=0)
    heading_curve = np.unwrap(np.arctan2(tangent[:, 1], tangent[:, 0]))
    heading = np.interp(distance, arc, heading_curve)
    heading = gaussian_smooth(heading, 8.0)

    yaw = heading.copy()
    pitch = np.full_like(yaw, math.radians(DEFAULT_PITCH_DEG))
    if spec.glances:
        yaw += np.radians(_eased_keys(frame, spec.glances, 1))
        pitch = np.radians(_eased_keys(frame, spec.glances, 2))
    for look in spec.looks:
        rise = _smoothstep((frame - look.start) / look.ramp)
        fall = 1.0 - _smoothstep((frame - (look.end - look.ramp)) / look.ramp)
        weight = np.minimum(rise, fall)
        offset = np.asarray(look.target, dtype=np.float64) - location
        target_yaw = np.arctan2(offset[:, 1], offset[:, 0])
        target_pitch = np.arctan2(offset[:, 2], np.hypot(offset[:, 0], offset[:, 1]))
        yaw = yaw + weight * _wrap(target_yaw - yaw)
        pitch = pitch + weight * (target_pitch - pitch)
    yaw = gaussian_smooth(np.unwrap(yaw), 3.0)
    pitch = gaussian_smooth(pitch, 3.0)
    return Track(location, yaw, pitch)
