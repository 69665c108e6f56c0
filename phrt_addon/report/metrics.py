"""Image error metrics of a rendered frame against a reference, and image I/O.

Every image enters as linear HDR RGB, float32, shape (H, W, 3), top row first.

- :func:`tonemap` is the one tone mapping applied to every image before an LDR
  metric (reference, raster, hybrid alike): clamp linear values to [0, 1] and
  apply the sRGB transfer function.  It is Blender's 'Standard' view
  transform, so a PNG written by Blender with 'Standard' holds exactly these
  values and EXR and PNG runs compare alike.  A plain clamp (no filmic
  curve) keeps errors in highlights visible instead of compressing them away.
- :func:`flip` is the mean LDR-FLIP (NVIDIA's ``flip_evaluator``, 67 pixels
  per degree) of the tone-mapped images: 0 for identical images, up to 1.
- :func:`relmse` is mean((test - ref)^2 / (ref^2 + 0.01)) over pixels and
  channels of the linear HDR images.
- :func:`psnr` is 10 log10(1 / MSE) of the tone-mapped images, in dB, capped
  at :data:`PSNR_CAP_DB` so identical images give a finite number.
- :func:`read_image` reads a Blender multilayer EXR (the Combined pass of the
  first view layer), a plain RGB(A) EXR, or an 8-bit sRGB PNG.  Blender 5.0
  writes one EXR part per pass, in view layer order, named
  ``<view layer>.<pass>`` with channels ``<view layer>.<pass>.<R|G|B|A|X|Y|Z>``
  (e.g. part ``ViewLayer.Combined``, channel ``ViewLayer.Combined.R``).  A
  single-part file with the same channel names (the older layout) is read
  too; EXR sorts a part's channels by name, so there the alphabetically first
  view layer wins.

Non-finite pixels are replaced (NaN by 0, +-Inf by +-65504, the float16
limit) so that every metric is finite.  Metrics are computed after rendering,
outside any timed region.  No ``bpy``; ``flip_evaluator`` and ``matplotlib``
are imported only by the functions that need them.
"""
from pathlib import Path

import numpy as np

from ..schema import COMBINED_PASS

PSNR_CAP_DB = 100.0
RELMSE_EPSILON = 0.01
HALF_MAX = 65504.0
# The pass whose RGB channels read_image returns from a multilayer EXR.


def linear_to_srgb(linear):
    """sRGB transfer function (IEC 61966-2-1) of values in [0, 1]."""
    linear = np.asarray(linear, dtype=np.float32)
    return np.where(linear <= 0.0031308, 12.92 * linear,
                    1.055 * np.power(np.maximum(linear, 0.0031308), 1.0 / 2.4) - 0.055
                    ).astype(np.float32)


def srgb_to_linear(encoded):
    """Inverse of :func:`linear_to_srgb`."""
    encoded = np.asarray(encoded, dtype=np.float32)
    return np.where(encoded <= 0.04045, encoded / 12.92,
                    np.power((np.maximum(encoded, 0.04045) + 0.055) / 1.055, 2.4)
                    ).astype(np.float32)


def tonemap(linear):
    """Linear HDR RGB -> sRGB-encoded LDR in [0, 1]: clamp, then sRGB encode."""
    return linear_to_srgb(np.clip(_as_rgb(linear), 0.0, 1.0))


def _as_rgb(image):
    image = np.asarray(image, dtype=np.float32)
    if image.ndim != 3 or image.shape[2] not in (3, 4):
        raise ValueError(f"expected an (H, W, 3) RGB image, got shape {image.shape}")
    return np.nan_to_num(image[..., :3], nan=0.0, posinf=HALF_MAX, neginf=-HALF_MAX)


def _pair(reference, test):
    reference, test = _as_rgb(reference), _as_rgb(test)
    if reference.shape != test.shape:
        raise ValueError(f"image sizes differ: reference {reference.shape[1]}x{reference.shape[0]}, "
                         f"test {test.shape[1]}x{test.shape[0]}")
    return reference, test


def flip(reference, test):
    """Mean LDR-FLIP between two linear HDR images (tone-mapped by :func:`tonemap`)."""
    import flip_evaluator

    reference, test = _pair(reference, test)
    _, mean_error, _ = flip_evaluator.evaluate(
        np.ascontiguousarray(tonemap(reference)), np.ascontiguousarray(tonemap(test)),
        "LDR", inputsRGB=True, applyMagma=False, computeMeanError=True)
    return max(float(mean_error), 0.0)


def flip_map(reference, test):
    """Per-pixel LDR-FLIP (H, W) between two linear HDR images (tone-mapped by :func:`tonemap`)."""
    import flip_evaluator

    reference, test = _pair(reference, test)
    error_map, _, _ = flip_evaluator.evaluate(
        np.ascontiguousarray(tonemap(reference)), np.ascontiguousarray(tonemap(test)),
        "LDR", inputsRGB=True, applyMagma=False, computeMeanError=False)
    error_map = np.asarray(error_map, dtype=np.float32)
    return np.clip(np.nan_to_num(error_map.reshape(reference.shape[:2]), nan=0.0), 0.0, 1.0)


def relmse(reference, test, epsilon=RELMSE_EPSILON):
    """Relative MSE of linear HDR images: mean((test - ref)^2 / (ref^2 + epsilon))."""
    reference, test = _pair(reference, test)
    reference, test = reference.astype(np.float64), test.astype(np.float64)
    return float(np.mean((test - reference) ** 2 / (reference ** 2 + epsilon)))


def psnr(reference, test, cap_db=PSNR_CAP_DB):
    """PSNR in dB of the tone-mapped images (peak 1), at most ``cap_db``."""
    reference, test = _pair(reference, test)
    mse = float(np.mean((tonemap(test).astype(np.float64) - tonemap(reference)) ** 2))
    return psnr_from_mse(mse, cap_db)


def psnr_from_mse(mse, cap_db=PSNR_CAP_DB):
    """10 log10(1 / mse) in dB for a peak of 1, at most ``cap_db``."""
    if mse <= 10.0 ** (-cap_db / 10.0):
        return float(cap_db)
    return float(min(cap_db, 10.0 * np.log10(1.0 / mse)))


def image_errors(reference, test):
    """All three metrics of ``test`` against ``reference``: keys flip, relmse, psnr_db."""
    reference, test = _pair(reference, test)
    return {"flip": flip(reference, test), "relmse": relmse(reference, test),
            "psnr_db": psnr(reference, test)}


def read_image(path):
    """Linear RGB float32 (H, W, 3), top row first, from a .exr or a .png file.

    Raises ``ValueError`` for an unsupported, missing or unreadable file.
    """
    path = Path(path)
    readers = {".exr": _read_exr, ".png": _read_png}
    suffix = path.suffix.lower()
    if suffix not in readers:
        raise ValueError(f"{path}: unsupported image type {suffix!r} (use .exr or .png)")
    try:
        return readers[suffix](path)
    except (OSError, RuntimeError, SyntaxError) as error:
        # OpenEXR raises RuntimeError, Pillow SyntaxError for a damaged file.
        raise ValueError(f"{path}: cannot read the image ({error})") from error


def _rgb_prefixes(names):
    """Prefixes p (e.g. 'ViewLayer.Combined.' or '') with channels pR, pG and pB."""
    present = set(names)
    prefixes = []
    for name in names:
        if name.endswith("R") and (len(name) == 1 or name[-2] == "."):
            prefix = name[:-1]
            if prefix + "G" in present and prefix + "B" in present and prefix not in prefixes:
                prefixes.append(prefix)
    return prefixes


def _read_exr(path):
    import OpenEXR

    with OpenEXR.File(str(path), separate_channels=True) as exr:
        channels = {}
        for part in exr.parts:
            for name, channel in part.channels.items():
                channels.setdefault(name, channel.pixels)
    prefixes = _rgb_prefixes(list(channels))
    combined = [p for p in prefixes if COMBINED_PASS in p.rstrip(".").split(".")]
    if combined or prefixes:
        prefix = (combined or ([""] if "" in prefixes else prefixes))[0]
        planes = [channels[prefix + c] for c in "RGB"]
    elif "Y" in channels:
        planes = [channels["Y"]] * 3
    else:
        raise ValueError(f"{path}: no RGB channels (has {sorted(channels)})")
    image = np.stack([np.asarray(plane, dtype=np.float32) for plane in planes], axis=-1)
    return np.nan_to_num(image, nan=0.0, posinf=HALF_MAX, neginf=-HALF_MAX)


def read_pass(path, pass_name):
    """One pass of a Blender multilayer EXR as float32 (H, W, channels), top row first,
    e.g. ``read_pass(path, "PHRT Element")``; ``ValueError`` if the file has no such pass."""
    return read_passes(path, (pass_name,))[pass_name]


_CHANNEL_ORDER = {"R": 0, "G": 1, "B": 2, "A": 3, "X": 0, "Y": 1, "Z": 2}


def read_passes(path, pass_names):
    """Several passes of one multilayer EXR, read once: {name: float32 (H, W, channels)} with
    channels in R, G, B, A (X, Y, Z) order; ``ValueError`` if a pass is missing."""
    import OpenEXR

    path = Path(path)
    try:
        with OpenEXR.File(str(path), separate_channels=True) as exr:
            channels = {}
            for part in exr.parts:
                for name, channel in part.channels.items():
                    channels.setdefault(name, channel.pixels)
    except (OSError, RuntimeError) as error:
        raise ValueError(f"{path}: cannot read the image ({error})") from error
    passes = {}
    for pass_name in pass_names:
        names = sorted(name for name in channels if name.rsplit(".", 1)[0].split(".")[-1] == pass_name)
        if not names:
            raise ValueError(f"{path}: no pass '{pass_name}'")
        layer = names[0].rsplit(".", 1)[0]
        names = sorted((name for name in names if name.rsplit(".", 1)[0] == layer),
                       key=lambda name: _CHANNEL_ORDER.get(name.rsplit(".", 1)[1], 9))
        image = np.stack([np.asarray(channels[name], dtype=np.float32) for name in names], axis=-1)
        passes[pass_name] = np.nan_to_num(image, nan=0.0, posinf=HALF_MAX, neginf=-HALF_MAX)
    return passes


def _read_png(path):
    import matplotlib.image

    encoded = np.asarray(matplotlib.image.imread(str(path)))
    if encoded.dtype == np.uint8:
        encoded = encoded / np.float32(255.0)
    if encoded.ndim == 2:
        encoded = np.repeat(encoded[..., None], 3, axis=2)
    return srgb_to_linear(encoded[..., :3])


def write_image(path, linear):
    """Write linear RGB (top row first) as a float32 RGB .exr or an 8-bit sRGB .png."""
    path = Path(path)
    linear = _as_rgb(linear)
    suffix = path.suffix.lower()
    if suffix == ".exr":
        import OpenEXR

        header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
        OpenEXR.File([OpenEXR.Part(header, {"RGB": np.ascontiguousarray(linear)})]).write(str(path))
    elif suffix == ".png":
        import matplotlib.image

        encoded = np.round(tonemap(linear) * 255.0).astype(np.uint8)
        matplotlib.image.imsave(str(path), encoded)
    else:
        raise ValueError(f"{path}: unsupported image type {suffix!r} (use .exr or .png)")
