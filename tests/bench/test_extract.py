"""``ssga extract``: any descriptor's features in hloc's HDF5 layout, written whole or not at all."""

from __future__ import annotations

import cv2
import h5py
import numpy as np
import pytest
from typer.testing import CliRunner

from ssga_core.cli import app_with_plugin_commands

app = app_with_plugin_commands()
runner = CliRunner()


@pytest.fixture
def images(tmp_path):
    rng = np.random.default_rng(0)
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    paths = [tmp_path / "a" / "one.png", tmp_path / "b" / "two.jpg"]
    cv2.imwrite(str(paths[0]), rng.integers(0, 256, (256, 256, 3), dtype=np.uint8))
    cv2.imwrite(str(paths[1]), rng.integers(0, 256, (120, 200, 3), dtype=np.uint8))
    return paths


def test_local_features_in_hlocs_layout(tmp_path, images, stand_ins):
    out = tmp_path / "features.h5"
    result = runner.invoke(app, ["extract", *map(str, images), "--descriptor", "test-patch-colour", "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert "b/two.jpg: resized from 200 x 120 to 256 x 256" in result.stderr
    with h5py.File(out) as h5:
        assert sorted(h5["a"]) == ["one.png"] and sorted(h5["b"]) == ["two.jpg"]
        group = h5["a/one.png"]
        keypoints, descriptors = group["keypoints"][()], group["descriptors"][()]
        assert keypoints.shape == (144, 2) and descriptors.shape == (3, 144) and descriptors.dtype == np.float32
        assert "resized_from" not in group.attrs
        assert list(h5["b/two.jpg"].attrs["resized_from"]) == [200, 120]
        # x then y: the grid's first row has one y and twelve x values
        assert len(set(keypoints[:12, 1])) == 1 and len(set(keypoints[:12, 0])) == 12
        # the descriptors are the image's: the mean colour near each keypoint, in [0, 1]
        image = cv2.cvtColor(cv2.imread(str(images[0])), cv2.COLOR_BGR2RGB) / 255.0
        x, y = np.rint(keypoints[0]).astype(int)
        assert np.allclose(descriptors[:, 0], image[y - 5 : y + 6, x - 5 : x + 6].reshape(-1, 3).mean(0), atol=0.1)
        assert h5.attrs["descriptor"] == "test-patch-colour"


def test_a_broken_image_stops_it_and_writes_nothing(tmp_path, images, stand_ins):
    broken = tmp_path / "broken.png"
    broken.write_bytes(b"\x89PNG not really")
    out = tmp_path / "features.h5"
    result = runner.invoke(app, ["extract", str(images[0]), str(broken), "--descriptor", "test-patch-colour", "--out", str(out)])
    assert result.exit_code == 1 and "Traceback" not in result.output
    assert "broken.png: not a readable image" in result.stderr
    assert not out.exists() and not list(tmp_path.glob(".features.h5*"))


def test_an_unknown_descriptor_or_option_is_one_line(tmp_path, images, stand_ins):
    result = runner.invoke(app, ["extract", str(images[0]), "--descriptor", "nope", "--out", str(tmp_path / "f.h5")])
    assert result.exit_code == 1 and "no descriptor named 'nope'" in result.stderr
    result = runner.invoke(app, ["extract", str(images[0]), "--descriptor", "dense-sift", "-o", "grid=0", "--out", str(tmp_path / "f.h5")])
    assert result.exit_code == 1 and "grid" in result.stderr and "Traceback" not in result.output
