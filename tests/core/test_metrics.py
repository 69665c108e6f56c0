"""Image metrics (tone mapping, LDR-FLIP, relMSE, PSNR) and EXR/PNG reading."""
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import OpenEXR
import pytest

from phrt.phrt_addon.report import metrics

DATA = Path(__file__).resolve().parent.parent / "data"
HEIGHT, WIDTH = 48, 64


def ldr_to_linear(value, shape=(HEIGHT, WIDTH, 3)):
    return metrics.srgb_to_linear(np.broadcast_to(np.float32(value), shape))


def smooth_image():
    y, x = np.mgrid[0:HEIGHT, 0:WIDTH].astype(np.float32)
    return np.stack([x / WIDTH, y / HEIGHT, 0.5 + 0.4 * np.sin(x / 5.0) * np.cos(y / 7.0)], axis=-1)


def write_exr(path, channels_per_part):
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    parts = [OpenEXR.Part(dict(header, name=name), channels) if name else
             OpenEXR.Part(header, channels) for name, channels in channels_per_part]
    OpenEXR.File(parts).write(str(path))


def test_tonemap_clamps_then_encodes_srgb():
    linear = np.array([[[0.0, 1.0, 2.0], [-1.0, 0.5, 0.0031308]]], dtype=np.float32)
    assert np.allclose(metrics.tonemap(linear),
                       [[[0.0, 1.0, 1.0], [0.0, 0.735357, 0.04045]]], atol=1e-5)


def test_srgb_round_trip():
    values = np.linspace(0.0, 1.0, 101, dtype=np.float32)
    assert np.allclose(metrics.linear_to_srgb(metrics.srgb_to_linear(values)), values, atol=1e-6)


def test_psnr_of_identical_images_is_the_finite_cap():
    image = smooth_image()
    assert metrics.psnr(image, image) == metrics.PSNR_CAP_DB == 100.0


def test_psnr_of_a_known_ldr_offset():
    reference = ldr_to_linear(0.4)
    assert metrics.psnr(reference, ldr_to_linear(0.5)) == pytest.approx(20.0, abs=1e-3)
    half = ldr_to_linear(0.4).copy()
    half[: HEIGHT // 2] = ldr_to_linear(0.6)[: HEIGHT // 2]
    # MSE = 0.5 * 0.2^2 = 0.02 -> 10 log10(50) dB.
    assert metrics.psnr(reference, half) == pytest.approx(16.9897, abs=1e-3)


def test_psnr_ignores_differences_above_white():
    assert metrics.psnr(np.full((4, 4, 3), 2.0), np.full((4, 4, 3), 5.0)) == 100.0


def test_relmse_known_values():
    image = smooth_image()
    assert metrics.relmse(image, image) == 0.0
    ones = np.ones((4, 4, 3), np.float32)
    assert metrics.relmse(ones, 2 * ones) == pytest.approx(1.0 / 1.01)
    assert metrics.relmse(0 * ones, 0.1 * ones) == pytest.approx(1.0)
    # HDR values count: relMSE sees what the clamped LDR metrics cannot.
    assert metrics.relmse(2 * ones, 5 * ones) == pytest.approx(9.0 / 4.01)


def test_flip_is_zero_for_identical_and_large_for_different_images():
    image = smooth_image()
    assert metrics.flip(image, image) == 0.0
    checker = (np.indices((HEIGHT, WIDTH)).sum(axis=0) // 4 % 2).astype(np.float32)
    different = np.repeat(checker[..., None], 3, axis=2)
    assert metrics.flip(image, different) > 0.1
    noisy = image + np.random.default_rng(1).normal(0.0, 0.01, image.shape).astype(np.float32)
    assert 0.0 < metrics.flip(image, noisy) < metrics.flip(image, different)


def test_image_errors_returns_all_three_metrics():
    errors = metrics.image_errors(ldr_to_linear(0.4), ldr_to_linear(0.5))
    assert set(errors) == {"flip", "relmse", "psnr_db"}
    assert errors["psnr_db"] == pytest.approx(20.0, abs=1e-3)
    assert errors["flip"] > 0.0 and errors["relmse"] > 0.0


def test_non_finite_pixels_give_finite_metrics():
    image = smooth_image()
    broken = image.copy()
    broken[0, 0] = (np.nan, np.inf, -np.inf)
    for value in metrics.image_errors(image, broken).values():
        assert np.isfinite(value)


def test_different_sizes_are_refused():
    with pytest.raises(ValueError, match="sizes differ"):
        metrics.relmse(np.zeros((4, 4, 3)), np.zeros((4, 5, 3)))


def test_blender_multilayer_exr_layout_is_one_part_per_pass():
    exr = OpenEXR.File(str(DATA / "blender501_phrt_passes.exr"), separate_channels=True)
    layout = {part.name(): sorted(part.channels) for part in exr.parts}
    assert layout == {
        "ViewLayer.Combined": ["ViewLayer.Combined.A", "ViewLayer.Combined.B",
                               "ViewLayer.Combined.G", "ViewLayer.Combined.R"],
        "ViewLayer.Depth": ["ViewLayer.Depth.Z"],
        "ViewLayer.Normal": ["ViewLayer.Normal.X", "ViewLayer.Normal.Y", "ViewLayer.Normal.Z"],
        "ViewLayer.PHRT Selected": ["ViewLayer.PHRT Selected.X"],
        "ViewLayer.PHRT Candidate": ["ViewLayer.PHRT Candidate.X"],
    }


def test_read_blender_exr_returns_combined_top_row_first():
    image = metrics.read_image(DATA / "blender501_phrt_passes.exr")
    assert image.shape == (24, 32, 3) and image.dtype == np.float32
    assert np.array_equal(image[0, 0], [2.0, 0.0, 0.0])           # HDR block, top-left
    assert image[4, 10, 1] == pytest.approx(19 / 23, abs=1e-3)     # G = rows from the bottom
    assert np.all(image[-1, :, 1] == 0.0)
    assert image[10, -1, 0] == pytest.approx(1.0, abs=1e-3) and image[10, 0, 0] == 0.0
    assert np.allclose(image[4:, :, 2], 0.25) and np.all(image[:4, :4, 2] == 0.0)


def test_blender_png_and_exr_of_one_render_read_alike():
    exr = metrics.read_image(DATA / "blender501_phrt_passes.exr")
    png = metrics.read_image(DATA / "blender501_phrt_passes.png")
    assert png.shape == exr.shape
    # Blender dithers 8-bit output: allow 2 levels.
    assert np.abs(metrics.tonemap(png) - metrics.tonemap(exr)).max() < 2.0 / 255.0
    assert metrics.psnr(exr, png) > 45.0


def test_read_workbench_exr_takes_combined_not_depth():
    image = metrics.read_image(DATA / "blender501_workbench.exr")
    assert image.shape == (24, 32, 3)
    assert 0.0 < image.max() <= 1.0


def test_read_multipart_picks_the_first_view_layers_combined(tmp_path):
    plane = np.zeros((3, 4), np.float32)
    parts = [("ViewLayer.Depth", {"ViewLayer.Depth.Z": plane + 9.0})]
    for layer, value in (("ViewLayer", 0.1), ("Another", 0.9)):
        parts.append((f"{layer}.Combined",
                      {f"{layer}.Combined.{c}": plane + value * (i + 1) for i, c in enumerate("RGBA")}))
    write_exr(tmp_path / "layers.exr", parts)
    assert np.allclose(metrics.read_image(tmp_path / "layers.exr"), [0.1, 0.2, 0.3])


def test_read_single_part_multilayer_picks_combined_over_other_colour_passes(tmp_path):
    plane = np.zeros((3, 4), np.float32)
    channels = {"ViewLayer.Depth.Z": plane + 9.0}
    for index, channel in enumerate("RGBA"):
        channels[f"ViewLayer.Combined.{channel}"] = plane + 0.1 * (index + 1)
        channels[f"ViewLayer.AColor.{channel}"] = plane + 0.7
    write_exr(tmp_path / "single.exr", [(None, channels)])
    assert np.allclose(metrics.read_image(tmp_path / "single.exr"), [0.1, 0.2, 0.3])


def test_read_plain_rgb_and_rgba_exr(tmp_path):
    plane = np.arange(12, dtype=np.float32).reshape(3, 4)
    write_exr(tmp_path / "rgb.exr", [(None, {"R": plane, "G": plane + 1, "B": plane + 2})])
    write_exr(tmp_path / "rgba.exr", [(None, {"R": plane, "G": plane + 1, "B": plane + 2,
                                              "A": plane * 0})])
    for name in ("rgb.exr", "rgba.exr"):
        image = metrics.read_image(tmp_path / name)
        assert np.array_equal(image[..., 0], plane) and np.array_equal(image[..., 2], plane + 2)


def test_exr_without_colour_is_refused(tmp_path):
    write_exr(tmp_path / "depth.exr", [("ViewLayer.Depth", {"ViewLayer.Depth.Z": np.ones((2, 2), "f")})])
    with pytest.raises(ValueError, match="no RGB channels"):
        metrics.read_image(tmp_path / "depth.exr")


def test_exr_and_png_rows_come_out_top_row_first(tmp_path):
    image = np.zeros((HEIGHT, WIDTH, 3), np.float32)
    image[0, :, 0] = 1.0          # top row red
    image[:, 0, 2] = 0.5          # left column blue
    metrics.write_image(tmp_path / "frame.exr", image)
    metrics.write_image(tmp_path / "frame.png", image)
    from_exr = metrics.read_image(tmp_path / "frame.exr")
    from_png = metrics.read_image(tmp_path / "frame.png")
    assert np.array_equal(from_exr, image)
    assert np.abs(metrics.tonemap(from_png) - metrics.tonemap(image)).max() <= 0.5 / 255 + 1e-6
    assert from_png[0, 5, 0] == pytest.approx(1.0) and from_png[-1, 5, 0] == 0.0


def test_png_written_by_matplotlib_is_linearised(tmp_path):
    encoded = np.full((2, 3, 3), 128, np.uint8)
    encoded[0, 0] = (255, 0, 0)
    plt.imsave(tmp_path / "grey.png", encoded)
    image = metrics.read_image(tmp_path / "grey.png")
    assert image.shape == (2, 3, 3)
    assert image[1, 1, 0] == pytest.approx(0.2158605, abs=1e-5)
    assert np.array_equal(image[0, 0], [1.0, 0.0, 0.0])


def test_unknown_image_type_is_refused(tmp_path):
    with pytest.raises(ValueError, match="unsupported"):
        metrics.read_image(tmp_path / "frame.jpg")


@pytest.mark.parametrize("name", ["damaged.exr", "damaged.png", "missing.exr"])
def test_unreadable_image_is_a_value_error(tmp_path, name):
    if name.startswith("damaged"):
        (tmp_path / name).write_bytes(b"not an image")
    with pytest.raises(ValueError, match="cannot read"):
        metrics.read_image(tmp_path / name)
