"""Training views of homes: records of arrays saved whole, and each home rendered once per settings."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ssga_bench import ArrayRecord, cached_homes


@dataclass
class Views(ArrayRecord):
    stored = {"depth": np.float16}
    loaded = {"depth": np.float32}

    rgb: np.ndarray
    depth: np.ndarray
    home: np.ndarray
    height: float = 1.5


def views(seed: int, count: int = 2, height: float = 1.5) -> Views:
    rng = np.random.default_rng(seed)
    return Views(rng.integers(0, 256, (count, 4, 4, 3), dtype=np.uint8), rng.uniform(0.5, 5, (count, 4, 4)).astype(np.float32), np.full(count, seed), height)


def test_a_record_saves_its_fields_at_their_stored_dtypes_and_loads_them_back(tmp_path):
    original = views(0, height=1.2)
    original.save(tmp_path / "v.npz")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["v.npz"], "nothing half-written left behind"
    with np.load(tmp_path / "v.npz") as f:
        assert f["depth"].dtype == np.float16 and f["height"].shape == ()
    back = Views.load(tmp_path / "v.npz")
    assert back.depth.dtype == np.float32 and np.allclose(back.depth, original.depth, rtol=1e-3)
    assert np.array_equal(back.rgb, original.rgb) and back.height == 1.2 and isinstance(back.height, float)


def test_records_concatenate_along_their_rows_and_keep_shared_scalars():
    both = Views.concat([views(0, 2, height=1.4), views(1, 3, height=1.4)])
    assert len(both) == 5 and both.home.tolist() == [0, 0, 1, 1, 1] and both.height == 1.4


def test_each_home_is_rendered_once_and_again_when_its_settings_change(tmp_path):
    rendered = []

    def render(seed):
        rendered.append(seed)
        return views(seed)

    first = cached_homes(tmp_path, "views", [3, 4], {"per_home": 2, "renderer": 1}, render, Views)
    again = cached_homes(tmp_path, "views", [4, 3], {"renderer": 1, "per_home": 2}, render, Views)
    assert rendered == [3, 4], "the second call reads both homes back (settings in any key order)"
    assert np.array_equal(first.rgb[:2], again.rgb[2:]) and again.home.tolist() == [4, 4, 3, 3]
    cached_homes(tmp_path, "views", [3], {"per_home": 2, "renderer": 2}, render, Views)
    assert rendered == [3, 4, 3], "a new renderer version renders the home again"
    assert len(list(tmp_path.glob("views-3-*.npz"))) == 2
