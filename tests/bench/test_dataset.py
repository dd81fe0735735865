"""Datasets on disk: atomic, resumable, and clear about what is wrong."""

from __future__ import annotations

import numpy as np
import pytest

from ssga_core import InputError
from ssga_bench.dataset import Dataset
from ssga_bench.dataset_build import build_dataset
from ssga_bench.protocol import ProtocolConfig
from ssga_bench.testing import WallWorkspaceSource

SMALL = ProtocolConfig(cells=2, test_per_class=1, seed=3)


class CountingWorkspace:
    """The stand-in wall workspace, counting renders and optionally failing after some."""

    def __init__(self, fail_after: int | None = None) -> None:
        self.inner = WallWorkspaceSource().open()
        self.name, self.camera, self.floor_plan = self.inner.name, self.inner.camera, self.inner.floor_plan
        self.camera_height = self.inner.camera_height
        self.renders, self.fail_after = 0, fail_after

    def render(self, pose):
        if self.fail_after is not None and self.renders >= self.fail_after:
            raise KeyboardInterrupt
        self.renders += 1
        return self.inner.render(pose)


def build(out, ws=None, protocol=SMALL, **kw):
    return build_dataset(ws or CountingWorkspace(), out, source={"name": "test-wall"}, protocol=protocol, **kw)


def test_a_dataset_round_trips_its_views(tmp_path):
    ws = CountingWorkspace()
    ds = build(tmp_path, ws)
    assert ws.renders == len(ds.plan.samples) == 2 * 12 + 24
    sample = ds.split("test")[0]
    view, rendered = ds.view(sample), ws.inner.render(sample.pose)
    np.testing.assert_array_equal(view.rgb, rendered.rgb)
    np.testing.assert_allclose(view.depth, rendered.depth, atol=0.0005)  # millimetres
    np.testing.assert_array_equal(view.semantic, rendered.semantic)
    assert ds.floor_plan.free.equals(ws.floor_plan.free)
    assert (tmp_path / "manifest.jsonl").read_text().count("\n") == len(ds.plan.samples)


def test_an_interrupted_build_resumes_without_redoing_work(tmp_path):
    with pytest.raises(KeyboardInterrupt):
        build(tmp_path, CountingWorkspace(fail_after=10))
    with pytest.raises(InputError, match="the build did not finish"):
        Dataset.open(tmp_path)
    assert not list(tmp_path.rglob("*.tmp"))
    resumed = CountingWorkspace()
    ds = build(tmp_path, resumed)
    assert resumed.renders == len(ds.plan.samples) - 10
    again = CountingWorkspace()
    build(tmp_path, again)
    assert again.renders == 0


def test_a_folder_built_with_other_settings_is_refused(tmp_path):
    build(tmp_path)
    with pytest.raises(InputError, match=r"holds a dataset built with other settings \(protocol\); use another folder or --overwrite"):
        build(tmp_path, protocol=ProtocolConfig(cells=2, test_per_class=1, seed=4))
    ds = build(tmp_path, protocol=ProtocolConfig(cells=2, test_per_class=1, seed=4), overwrite=True)
    assert ds.plan.config.seed == 4


def test_broken_and_missing_files_are_named(tmp_path):
    ds = build(tmp_path)
    sample = ds.split("train")[0]
    (tmp_path / "rgb" / f"{sample.id}.png").write_bytes(b"not a png")
    with pytest.raises(InputError, match=rf"rgb/{sample.id}.png: not a readable image"):
        ds.view(sample)
    (tmp_path / "depth" / f"{sample.id}.png").unlink()
    (tmp_path / "rgb" / f"{sample.id}.png").unlink()
    with pytest.raises(InputError, match=rf"rgb/{sample.id}.png: no such file"):
        ds.view(sample)
    with pytest.raises(InputError, match="not an ssga dataset"):
        Dataset.open(tmp_path / "nothing")
