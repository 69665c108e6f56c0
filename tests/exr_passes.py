"""Reading every pass of a PHRT multilayer EXR in tests (top row first)."""
import numpy as np
import OpenEXR


def read_passes(path) -> dict:
    """{pass name: float32 (h, w) or (h, w, c)} from Blender 5.x's one-part-per-pass EXR
    or 4.5's single part (channels are 'ViewLayer.<pass>.<component>' in both)."""
    passes = {}
    with OpenEXR.File(str(path), separate_channels=True) as exr:
        for part in exr.parts:
            by_pass = {}
            for channel_name, channel in part.channels.items():
                layer, _, rest = channel_name.partition(".")
                pass_name, _, component = rest.rpartition(".")
                by_pass.setdefault(pass_name, {})[component] = np.asarray(channel.pixels, dtype=np.float32)
            for pass_name, components in by_pass.items():
                order = [c for c in "RGBAXYZ" if c in components] or sorted(components)
                stacked = np.stack([components[c] for c in order], axis=-1)
                passes[pass_name] = stacked[..., 0] if stacked.shape[-1] == 1 else stacked
    return passes
