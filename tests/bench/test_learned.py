"""The learned-stage kit: checkpoint errors are one line naming the field and file; random weights are labelled."""

from __future__ import annotations

import pytest
import torch

from ssga_bench.learned import (
    Layout,
    Learned,
    LearnedConfig,
    checkpoint_bytes,
    file_stamp,
    find_weights,
    load_checkpoint,
    load_strict,
    meta_shapes,
    read_layout,
    resolve_device,
)
from ssga_bench.testing import one_line_checkpoint_error
from ssga_core.errors import CheckpointError, InputError


def net() -> torch.nn.Module:
    return torch.nn.Sequential(torch.nn.Conv2d(3, 4, 3), torch.nn.ReLU(), torch.nn.Conv2d(4, 2, 1))


def test_a_matching_checkpoint_loads_strictly(tmp_path):
    source = net()
    path = tmp_path / "w.pt"
    path.write_bytes(checkpoint_bytes({"state_dict": source.state_dict()}))
    target = net()
    load_strict(target, load_checkpoint(path, "descriptor 'x'")["state_dict"], "descriptor 'x'", path)
    assert all(torch.equal(a, b) for a, b in zip(source.state_dict().values(), target.state_dict().values()))


def test_mismatched_keys_and_shapes_are_named(tmp_path):
    state = net().state_dict()
    state["2.weight"] = torch.zeros(5, 4, 1, 1)
    state["extra"] = torch.zeros(1)
    del state["0.bias"]
    message = one_line_checkpoint_error(lambda: load_strict(net(), state, "descriptor 'x'", tmp_path / "w.pt"), "'weights'", "w.pt")
    assert "1 missing: 0.bias" in message and "1 unexpected: extra" in message and "2.weight (5, 4, 1, 1)" in message


def test_corrupt_and_missing_files_are_one_line(tmp_path):
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"not a checkpoint")
    with pytest.raises(CheckpointError, match="bad.pt is not a readable checkpoint") as err:
        load_checkpoint(bad, "parser 'y'")
    assert "\n" not in str(err.value)
    with pytest.raises(CheckpointError, match="'weights' = 'nope.pt': no such file"):
        find_weights("nope.pt", tmp_path, "parser 'y'")


def test_a_packaged_file_is_found_before_the_working_directory(tmp_path, monkeypatch):
    (tmp_path / "pkg").mkdir()
    (tmp_path / "pkg" / "w.pt").write_bytes(b"x")
    monkeypatch.chdir(tmp_path)
    assert find_weights("w.pt", tmp_path / "pkg", "s") == tmp_path / "pkg" / "w.pt"


def test_random_weights_carry_a_caveat():
    class Stage(Learned):
        pass

    assert Stage.caveat(LearnedConfig()) == "random weights"
    assert Stage.caveat(LearnedConfig(weights="w.pt")) == ""


def test_cuda_asked_without_cuda_is_an_error():
    if torch.cuda.is_available():
        pytest.skip("this machine has CUDA")
    assert resolve_device("auto").type == "cpu"
    with pytest.raises(InputError, match="sees no CUDA device"):
        resolve_device("cuda")


class Loaded(Learned):
    """A stage whose network and vocabulary come from ``_load`` (counted), as detic's do."""

    reloaded = ("net", "names")
    loads = 0

    def __init__(self) -> None:
        self.config = LearnedConfig()
        self.net, self.names = self._load()

    def _load(self):
        type(self).loads += 1
        torch.manual_seed(0)  # as a stage on random weights: the same network in every process
        return net(), ("wall", "floor")


def test_a_pickled_stage_loads_its_own_network_instead_of_carrying_it():
    import pickle

    stage = Loaded()
    data = pickle.dumps(stage)
    assert b"torch" not in data and len(data) < 1000, "the network is not in the pickle"
    copy = pickle.loads(data)
    assert Loaded.loads == 2 and copy.names == ("wall", "floor")
    assert all(torch.equal(a, b) for a, b in zip(stage.net.state_dict().values(), copy.net.state_dict().values(), strict=True))
    assert pickle.loads(pickle.dumps(Learned())).__dict__ == {}, "a stage that reloads nothing pickles as it is"


class NetConfig(LearnedConfig):
    network: str | None = None
    width: int | None = None


LAYOUTS = (Layout("narrow", "trained here"), Layout("wide", "an official release"))


def network_of(layout: Layout, state) -> tuple[dict, dict]:
    """A two-layer network whose first width is read from the file, as official loaders read sizes."""
    first = state.get("0.weight")
    width = int(first.shape[0]) if first is not None else 4
    channels = 3 if layout.name == "narrow" else 6
    return {"network": layout.name, "width": width}, meta_shapes(
        lambda: torch.nn.Sequential(torch.nn.Conv2d(channels, width, 3), torch.nn.ReLU(), torch.nn.Conv2d(width, 2, 1))
    )


def test_a_file_names_its_layout_and_the_sizes_read_from_it():
    wide = torch.nn.Sequential(torch.nn.Conv2d(6, 7, 3), torch.nn.ReLU(), torch.nn.Conv2d(7, 2, 1)).state_dict()
    layout, fields = read_layout(NetConfig(), wide, LAYOUTS, network_of, "parser 'x'", "w.pt")
    assert layout.name == "wide" and fields == {"network": "wide", "width": 7}
    # A field the config leaves out or sets to what the file holds is no contradiction.
    assert read_layout(NetConfig(network="wide", width=7), wide, LAYOUTS, network_of, "parser 'x'", "w.pt")[1] == fields


def test_a_contradicting_config_names_both_and_an_unknown_file_the_closest_layout():
    wide = torch.nn.Sequential(torch.nn.Conv2d(6, 7, 3), torch.nn.ReLU(), torch.nn.Conv2d(7, 2, 1)).state_dict()
    with pytest.raises(CheckpointError) as err:
        read_layout(NetConfig(network="narrow", width=3), wide, LAYOUTS, network_of, "parser 'x'", "w.pt")
    assert str(err.value) == (
        "parser 'x': config fields network = 'narrow', width = 3 contradict config field 'weights': w.pt holds the 'wide' layout "
        "(an official release) with network = 'wide', width = 7; leave network, width out to take the file's"
    )
    odd = dict(wide)
    odd["2.weight"] = torch.zeros(5, 7, 1, 1)
    with pytest.raises(CheckpointError) as err:
        read_layout(NetConfig(), odd, LAYOUTS, network_of, "parser 'x'", "w.pt")
    assert str(err.value) == (
        "parser 'x': config field 'weights': w.pt matches none of the layouts it loads ('narrow', 'wide'); "
        "closest: 'wide': 1 wrong shape: 2.weight (5, 7, 1, 1) (expected (2, 7, 1, 1))"
    )


def test_packaged_weights_on_another_kind_of_workspace_are_flagged(tmp_path):
    packaged = tmp_path / "weights"
    packaged.mkdir()
    (packaged / "light.pt").write_bytes(b"")
    (tmp_path / "official.pt").write_bytes(b"")

    class Stage(Learned):
        kind, name = "descriptor", "x"
        packaged_weights = packaged
        trained_on = "procedural"

    warning = Stage.out_of_domain(LearnedConfig(weights="light.pt"), "mesh")
    assert warning == "descriptor 'x' runs the weights trained here on procedural homes (light.pt), not on views like this 'mesh' workspace's"
    assert Stage.out_of_domain(LearnedConfig(weights=str(packaged / "light.pt")), "folder")  # the same file by its path
    assert Stage.out_of_domain(LearnedConfig(weights="light.pt"), "procedural") == ""  # the homes they were trained on
    assert Stage.out_of_domain(LearnedConfig(weights=str(tmp_path / "official.pt")), "mesh") == ""  # a user's file
    assert Stage.out_of_domain(LearnedConfig(weights="random"), "mesh") == ""  # labelled as random already


def test_what_a_stage_loads_is_loaded_once_per_process_and_key(tmp_path):
    loads = []

    class Stage(Learned):
        kind, name = "descriptor", "x"
        config = LearnedConfig()

    class Other(Stage):
        name = "y"

    weights = tmp_path / "w.pt"
    weights.write_bytes(b"one")
    key = (file_stamp(weights), "light", "cpu")
    first = Stage().once_per_process(key, lambda: loads.append("x") or object())
    assert Stage().once_per_process(key, lambda: loads.append("again") or object()) is first  # another instance: shared
    Other().once_per_process(key, lambda: loads.append("y") or object())  # another stage: its own
    weights.write_bytes(b"changed")  # a new file under the same name: loaded anew
    Stage().once_per_process((file_stamp(weights), "light", "cpu"), lambda: loads.append("x2") or object())
    assert loads == ["x", "y", "x2"]
