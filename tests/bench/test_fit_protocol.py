"""A workspace that fits itself: where the configured protocol does not fit, values that do are chosen, said and recorded."""

from __future__ import annotations

import json

import pytest

from ssga_bench.dataset_build import build_dataset
from ssga_bench.protocol import ProtocolConfig
from ssga_bench.testing import WallWorkspaceSource
from ssga_core import InputError

TOO_BIG_CELLS = ProtocolConfig(cells=2, cell_size=30.0, test_per_class=2, seed=4)
"""30 m cells in a 10 m room: none is seen from every heading."""
TOO_SMALL_A_RADIUS = ProtocolConfig(cells=2, test_per_class=3, test_radius=0.01, max_candidates=8, seed=4)
"""Test cameras within 1 cm of a centroid, eight candidates per view: some classes get none."""


def build(tmp_path, name, protocol, fit):
    return build_dataset(WallWorkspaceSource().open(), tmp_path / name, source={"name": "test-wall"}, protocol=protocol, fit=fit)


@pytest.mark.parametrize(("protocol", "changed", "value"), [(TOO_BIG_CELLS, "cell_size", 3.0), (TOO_SMALL_A_RADIUS, "test_radius", 1.0)])
def test_a_protocol_that_does_not_fit_is_fitted_said_and_recorded(tmp_path, capsys, monkeypatch, protocol, changed, value):
    with pytest.raises(InputError) as fixed:
        build(tmp_path, "fixed", protocol, fit=False)
    dataset = build(tmp_path, "fitted", protocol, fit=True)
    said = capsys.readouterr().err
    assert said.count("\n") == 1 and f"the protocol was fitted to it: protocol.{changed} = {value:g} (configured {getattr(protocol, changed):g})" in said
    record = json.loads((tmp_path / "fitted" / "fitted.json").read_text())
    assert record == {"fitted": {changed: value}, "configured": {changed: getattr(protocol, changed)}, "because": str(fixed.value)}
    assert dataset.split("test") and dataset.plan.config.model_dump()[changed] == value
    # Built: reopened as it is, without fitting again.
    monkeypatch.setattr("ssga_bench.dataset_build.fit_protocol", lambda *a, **k: pytest.fail("fitted again"))
    again = build(tmp_path, "fitted", protocol, fit=True)
    assert again.plan.config.model_dump()[changed] == value and [s.id for s in again.split("test")] == [s.id for s in dataset.split("test")]


def test_what_no_value_fits_names_every_setting_that_would_at_once(tmp_path):
    hopeless = TOO_SMALL_A_RADIUS.model_copy(update={"max_candidates": 1})
    with pytest.raises(InputError) as failed:
        build(tmp_path, "hopeless", hopeless, fit=True)
    message = str(failed.value)
    assert "\n" not in message and "cannot all be placed at any test_radius tried" in message
    assert all(f"protocol.{name}" in message for name in ("test_per_class", "val_per_class", "max_candidates"))
    assert not (tmp_path / "hopeless" / "plan.json").exists()


def test_scans_and_captures_fit_by_default_the_embedded_homes_do_not(ssga_installed_registry):
    fits = {name: ssga_installed_registry.entry("workspace", name).cls.fits_protocol for name in ("mesh", "folder", "procedural")}
    assert fits == {"mesh": True, "folder": True, "procedural": False}
    assert ProtocolConfig().fit is None and ProtocolConfig(fit="fixed").fit == "fixed"
