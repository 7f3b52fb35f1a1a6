"""dotsim.images.read_grey_image against files written by other libraries (Pillow PNGs, OpenEXR EXRs)
and hashlib checksums of the bytes on disk."""

import hashlib

import numpy as np
import OpenEXR
import pytest
from PIL import Image

from dotsim.images import GreyImage, ImageError, read_grey_image


def _write_exr(path, channels):
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    OpenEXR.File(header, {name: np.ascontiguousarray(v) for name, v in channels.items()}).write(str(path))


def _pillow_write(path, array):
    """Write with Pillow (not OpenCV, which the reader uses); the mode follows the array's shape/dtype."""
    Image.fromarray(array).save(path)
    return path


@pytest.mark.parametrize("dtype, white", [(np.uint8, 255.0), (np.uint16, 65535.0)])
def test_png_values_white_level_and_checksum(tmp_path, dtype, white):
    values = np.random.default_rng(1).integers(0, int(white), (13, 21), endpoint=True).astype(dtype)
    path = _pillow_write(tmp_path / "grey.png", values)
    image = read_grey_image(path)
    assert isinstance(image, GreyImage)
    assert image.pixels.dtype == dtype and image.white_level == white
    np.testing.assert_array_equal(image.pixels, values)
    np.testing.assert_array_equal(image.relative(), values / white)
    np.testing.assert_array_equal(image.relative(1000.0), values / 1000.0)
    assert image.sha256 == hashlib.sha256(path.read_bytes()).hexdigest()


def test_grey_saved_as_rgb_or_with_alpha_is_grey(tmp_path):
    grey = np.random.default_rng(2).integers(0, 255, (9, 11), endpoint=True).astype(np.uint8)
    rgb = _pillow_write(tmp_path / "rgb.png", np.dstack([grey] * 3))
    rgba = _pillow_write(tmp_path / "rgba.png", np.dstack([grey] * 3 + [np.full_like(grey, 17)]))
    grey_alpha = _pillow_write(tmp_path / "la.png", np.dstack([grey, 255 - grey]))
    for path in (rgb, rgba, grey_alpha):
        np.testing.assert_array_equal(read_grey_image(path).pixels, grey)


def test_exr_channel_choice_and_values(tmp_path):
    rng = np.random.default_rng(3)
    ir, y, r, other = (rng.random((7, 5), dtype=np.float32) * 4 for _ in range(4))
    cases = {"ir": ({"ir": ir, "Y": y, "depth": other}, ir), "IR": ({"IR": ir, "R": r}, ir),
             "Y": ({"Y": y, "R": r}, y), "R": ({"R": r, "G": other, "B": other}, r),
             "single": ({"anything": other}, other)}
    for name, (channels, expected) in cases.items():
        path = tmp_path / f"{name}.exr"
        _write_exr(path, channels)
        image = read_grey_image(path)
        assert image.pixels.dtype == np.float32 and image.white_level == 1.0, name
        np.testing.assert_array_equal(image.pixels, expected, err_msg=name)
        assert image.sha256 == hashlib.sha256(path.read_bytes()).hexdigest()


def test_half_exr_is_read_as_its_float32_values(tmp_path):
    half = (np.arange(12, dtype=np.float32).reshape(3, 4) / 7).astype(np.float16)
    _write_exr(tmp_path / "half.exr", {"Y": half})
    np.testing.assert_array_equal(read_grey_image(tmp_path / "half.exr").pixels, half.astype(np.float32))


def test_bad_images_are_refused_naming_the_file(tmp_path):
    def refused(path, match):
        with pytest.raises(ImageError, match=match):
            read_grey_image(path)

    refused(tmp_path / "missing.png", "missing.png: no such file")
    refused(tmp_path, f"{tmp_path}: is a folder, not a file")
    (tmp_path / "empty.exr").write_bytes(b"")
    refused(tmp_path / "empty.exr", "empty.exr: file is empty")
    (tmp_path / "text.png").write_text("not a picture")
    refused(tmp_path / "text.png", "text.png: not a readable PNG image")
    (tmp_path / "text.exr").write_text("not a picture")
    refused(tmp_path / "text.exr", "text.exr: not a readable EXR image")
    grey = np.arange(20, dtype=np.uint8).reshape(4, 5)
    _pillow_write(tmp_path / "colour.png", np.dstack([grey, grey, grey + 1]))
    refused(tmp_path / "colour.png", r"colour.png: colour image \(its channels differ\)")
    _write_exr(tmp_path / "two.exr", {"A": np.ones((3, 3), np.float32), "Z": np.ones((3, 3), np.float32)})
    refused(tmp_path / "two.exr", r"two.exr: EXR has channels \['A', 'Z'\]; expected one channel or one "
                                  "named ir, IR, Y, R")
    nan = np.ones((4, 4), np.float32)
    nan[1, 2] = np.nan
    nan[3, 0] = np.inf
    _write_exr(tmp_path / "nan.exr", {"Y": nan})
    refused(tmp_path / "nan.exr", "nan.exr: image contains 2 NaN/inf pixels")
    _pillow_write(tmp_path / "float.tiff", np.ones((3, 3), np.float32))
    refused(tmp_path / "float.tiff", "float.tiff: sample type float32 unsupported")
