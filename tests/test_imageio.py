"""Image files in the format their suffix names, through the API and the CLI."""

import io

import numpy as np
import pytest
from PIL import Image

from raykernel.cli import main
from raykernel.errors import OptionError
from raykernel.rendering.imageio import FORMATS, save_image, to_uint8


def gradient(h=6, w=5):
    y, x = np.mgrid[0:h, 0:w]
    return np.stack([x / (w - 1), y / (h - 1), np.full((h, w), 1.5)], axis=-1)   # blue past 1: HDR


@pytest.mark.parametrize("suffix,fmt", [(".png", "PNG"), (".jpg", "JPEG"), (".jpeg", "JPEG"), (".tif", "TIFF"),
                                        (".tiff", "TIFF"), (".webp", "WEBP")])
def test_eight_bit_formats_are_what_the_suffix_says(tmp_path, suffix, fmt):
    img = gradient()
    path = tmp_path / f"out{suffix}"
    save_image(img, path)
    with Image.open(path) as f:
        assert f.format == fmt
        assert f.size == (5, 6)
        pixels = np.asarray(f.convert("RGB"))
    if fmt in ("PNG", "TIFF"):          # lossless
        np.testing.assert_array_equal(pixels, to_uint8(img))
    else:
        assert np.abs(pixels.astype(int) - to_uint8(img)).max() < 40


def test_npy_keeps_the_float_image(tmp_path):
    img = gradient()
    save_image(img, tmp_path / "out.npy")
    np.testing.assert_array_equal(np.load(tmp_path / "out.npy"), img)


def test_pfm_is_little_endian_float_bottom_up(tmp_path):
    img = gradient()
    save_image(img, tmp_path / "out.pfm")
    data = (tmp_path / "out.pfm").read_bytes()
    header, rest = data.split(b"\n", 3)[:3], data.split(b"\n", 3)[3]
    assert header == [b"PF", b"5 6", b"-1.0"]
    pixels = np.frombuffer(rest, "<f4").reshape(6, 5, 3)[::-1]
    np.testing.assert_array_equal(pixels, img.astype(np.float32))


def test_exr_round_trips_when_openexr_is_installed(tmp_path):
    OpenEXR = pytest.importorskip("OpenEXR")
    img = gradient()
    save_image(img, tmp_path / "out.exr")
    with OpenEXR.File(str(tmp_path / "out.exr")) as f:
        channels = f.channels()
        rgb = channels["RGB"].pixels if "RGB" in channels else np.stack(
            [channels[c].pixels for c in "RGB"], axis=-1)
    np.testing.assert_array_equal(rgb, img.astype(np.float32))


@pytest.mark.parametrize("name", ["out.gif", "out.bmp", "out", "out.PNG.txt"])
def test_unknown_suffix_is_refused_with_the_list(tmp_path, name):
    with pytest.raises(OptionError) as err:
        save_image(gradient(), tmp_path / name)
    for suffix in FORMATS:
        assert suffix in str(err.value)
    assert not (tmp_path / name).exists()


def test_suffix_case_does_not_matter(tmp_path):
    save_image(gradient(), tmp_path / "OUT.JPG")
    with Image.open(tmp_path / "OUT.JPG") as f:
        assert f.format == "JPEG"


def test_cli_writes_jpeg_for_jpg(tmp_path, capsys):
    out = tmp_path / "balls.jpg"
    assert main(["render", "spd:balls:1", "-o", str(out), "--resolution", "8"]) == 0
    with Image.open(out) as f:
        assert f.format == "JPEG"
    assert io.BytesIO(out.read_bytes()).read(2) == b"\xff\xd8"


def test_cli_refuses_an_unknown_format_before_rendering(tmp_path, capsys):
    out = tmp_path / "balls.gif"
    assert main(["render", "spd:balls:1", "-o", str(out), "--resolution", "8"]) == 2
    err = capsys.readouterr().err
    assert ".gif" in err and ".png" in err and ".exr" in err
    assert not out.exists()
