"""Images of any size and kind: read reduced while decoded, said so, in bounded memory."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from PIL import Image

from ssga_bench.io import read_rgb

GiB = 1024**3
PEAK_OF = (
    "import resource, subprocess, sys; done = subprocess.run(sys.argv[1:]); "
    "print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss, file=sys.stderr); sys.exit(done.returncode)"
)


def gradient(width: int, height: int) -> np.ndarray:
    """A smooth RGB picture (cheap to encode at any size, and not all one colour)."""
    u = np.linspace(0, 255, width, dtype=np.float32)[None, :]
    v = np.linspace(0, 255, height, dtype=np.float32)[:, None]
    return np.stack(np.broadcast_arrays(u + 0 * v, v + 0 * u, (u + v) / 2), axis=-1).astype(np.uint8)


def test_a_large_jpeg_is_decoded_reduced_then_resized_exactly(tmp_path, monkeypatch):
    path = tmp_path / "photo.jpg"
    cv2.imwrite(str(path), gradient(4000, 3000))
    flags = []
    real = cv2.imread
    monkeypatch.setattr(cv2, "imread", lambda p, f=cv2.IMREAD_COLOR: flags.append(f) or real(p, f))
    rgb, original = read_rgb(path, 1024)
    assert rgb.shape == (768, 1024, 3) and rgb.dtype == np.uint8 and original == (4000, 3000)
    assert flags == [cv2.IMREAD_REDUCED_COLOR_2]  # 2000 x 1500 decoded, never 4000 x 3000
    assert read_rgb(path, 8000)[1] is None and read_rgb(path, None)[0].shape == (3000, 4000, 3)


def test_exif_orientation_and_every_kind_of_image_come_as_rgb(tmp_path):
    turned = tmp_path / "turned.jpg"
    exif = Image.Exif()
    exif[0x0112] = 6  # "rotate 90 CW to view": a phone held upright
    Image.fromarray(gradient(400, 200)).save(turned, exif=exif)
    assert read_rgb(turned, 1024)[0].shape == (400, 200, 3)
    kinds = {
        "grey.png": Image.fromarray(gradient(64, 32)[..., 0]),
        "rgba.png": Image.fromarray(np.dstack([gradient(64, 32), np.full((32, 64), 128, np.uint8)])),
        "palette.png": Image.fromarray(gradient(64, 32)).convert("P"),
        "sixteen.png": Image.fromarray(gradient(64, 32)[..., 0].astype(np.uint16) * 257),
    }
    for name, image in kinds.items():
        image.save(tmp_path / name)
        rgb, original = read_rgb(tmp_path / name, 16)
        assert rgb.shape == (8, 16, 3) and rgb.dtype == np.uint8 and original == (64, 32), name


@pytest.mark.parametrize("command", ["parse", "synthesize", "extract"])
def test_a_12000_pixel_photo_stays_under_1_5_gib_and_is_said_reduced(tmp_path, command):
    photo = tmp_path / "photo.jpg"
    cv2.imwrite(str(photo), gradient(12000, 12000), [cv2.IMWRITE_JPEG_QUALITY, 80])
    args = {
        "parse": ["parse", str(photo), "--parser", "slico", "--out", str(tmp_path / "out"), "--executor", "serial"],
        "synthesize": ["synthesize", str(photo), "--synthesizer", "midas-warp", "--move", "0.3,0,10", "--out", str(tmp_path / "out")],
        "extract": ["extract", str(photo), "--descriptor", "dense-sift", "--out", str(tmp_path / "features.h5"), "--executor", "serial"],
    }[command]
    # A fresh interpreter whose only child is the command: its children's peak RSS is the command's.
    done = subprocess.run([sys.executable, "-c", PEAK_OF, str(Path(sys.executable).parent / "ssga"), *args], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout + done.stderr
    peak = int(done.stderr.strip().splitlines()[-1]) * 1024  # kB on Linux
    assert peak < 1.5 * GiB, f"{command}: peak {peak / GiB:.2f} GiB"
    if command == "parse":
        assert "its 12000 x 12000 read reduced to --max-side 1024" in done.stdout
        record = json.loads((tmp_path / "out" / "photo.regions.json").read_text())
        assert record["size"] == [1024, 1024] and record["resized_from"] == [12000, 12000]
    elif command == "synthesize":
        assert "read reduced to --max-side 1024" in done.stdout
        assert cv2.imread(str(tmp_path / "out" / "synthetic.png")).shape == (1024, 1024, 3)
