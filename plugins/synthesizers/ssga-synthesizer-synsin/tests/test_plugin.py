"""The synsin synthesizer as ssga sees it: registration, contract, point map, caveat, the layout a file names, loading errors, packaged weights."""

from __future__ import annotations

import pickle

import numpy as np
import pytest
import torch
from pydantic import ValidationError
from ssga_core.testing import check_synthesizer, check_synthesizer_in_all_orders, make_view
from ssga_synthesizer_synsin.model import LightOptions, SynSinLight
from ssga_synthesizer_synsin.plugin import LIGHT_WEIGHTS, WEIGHTS_DIR, SynSinConfig, SynSinSynthesizer

from ssga_bench import checkpoint_bytes, validate_experiment
from ssga_bench.testing import one_line_checkpoint_error, packaged_provenance
from ssga_core import Camera, CheckpointError, InputError, Pose, View

RANDOM = SynSinConfig(weights="random", device="cpu")
TRAINED = SynSinConfig(device="cpu")


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    return float(10 * np.log10(255.0**2 / ((a.astype(np.float64) - b) ** 2).mean()))


@pytest.fixture(scope="module")
def trained() -> SynSinSynthesizer:
    return SynSinSynthesizer(TRAINED)


def test_is_installed_and_registered(ssga_installed_registry):
    entry = ssga_installed_registry.entry("synthesizer", "synsin")
    assert entry.cls is SynSinSynthesizer
    assert entry.plugin.distribution == "ssga-synthesizer-synsin"


def test_meets_the_synthesizer_contract(trained):
    check_synthesizer(trained, make_view(seed=0, size=128))
    check_synthesizer(SynSinSynthesizer(RANDOM), make_view(seed=7, size=96, distance=1.2))


def test_runs_in_every_order(trained):
    check_synthesizer_in_all_orders(trained, make_view(seed=3, size=48))


def test_needs_rgb_only_and_gives_depth():
    view = make_view(size=64)
    flat = View(rgb=view.rgb, pose=view.pose, camera=view.camera)  # no depth
    syn = SynSinSynthesizer(RANDOM).synthesize(flat, Pose(0.2, 0.1, 0.1))
    assert syn.view.synthetic and syn.view.depth is not None and syn.view.depth.dtype == np.float32
    assert SynSinSynthesizer.consumes == {"rgb"} and {"depth", "point-map"} <= SynSinSynthesizer.produces


def test_the_identity_move_reproduces_the_input(trained):
    """At its own pose every pixel lands on itself; the trained network redraws the image closely.

    Measured (dB, identity / the image shifted by one pixel): make_view walls 31.9 / 27.0 and
    31.4 / 28.0; scikit-image's astronaut and cat at 256 x 256 27.0 / 21.6 and 33.4 / 26.8;
    held-out procedural homes 35.2 / 31.2 and 30.5 / 25.0.
    """
    views = [make_view(seed=1), make_view(seed=2, distance=1.5)]
    data = pytest.importorskip("skimage.data")
    resize = pytest.importorskip("skimage.transform").resize
    for image in (data.astronaut(), data.chelsea()):
        rgb = (resize(image, (256, 256), anti_aliasing=True) * 255).round().astype(np.uint8)
        views.append(View(rgb=rgb, pose=Pose(1.0, 2.0, 0.5)))
    for view, floor in zip(views, (29.0, 29.0, 25.5, 31.0), strict=True):
        syn = trained.synthesize(view, view.pose)
        assert syn.visible.all()
        np.testing.assert_allclose(syn.target_uv, view.camera.pixel_grid(), atol=1e-3)
        assert psnr(syn.view.rgb, view.rgb) > floor
        assert psnr(syn.view.rgb, view.rgb) > psnr(np.roll(view.rgb, 1, axis=1), view.rgb) + 3.0


def test_the_point_map_is_the_predicted_depth_moved_by_the_core_geometry(trained):
    view = make_view(seed=4, size=96)
    target = Pose(0.3, -0.2, 0.25)
    syn = trained.synthesize(view, target)
    depth = trained.predict_depth(view)
    assert depth.shape == (96, 96) and (depth >= 0.5).all() and (depth <= 10.0).all()
    T = target.relative_to(view.pose)
    uv, z = view.camera.project(view.camera.unproject(depth) @ T[:3, :3].T + T[:3, 3])
    np.testing.assert_allclose(syn.target_uv, uv, atol=1e-3)
    # visible: inside the target image and within 2% of the nearest point on its own (nearest) pixel
    inside = view.camera.contains(uv)
    rows, cols = np.rint(uv[inside][:, 1]).astype(int), np.rint(uv[inside][:, 0]).astype(int)
    zbuf = np.full(view.camera.shape, np.inf)
    np.minimum.at(zbuf, (rows, cols), z[inside])
    front = np.zeros_like(inside)
    front[inside] = z[inside] <= zbuf[rows, cols] * 1.02
    np.testing.assert_array_equal(syn.visible, front)
    assert 0.5 < front.mean() < 1.0
    # the synthetic depth is the front-most point within the splat radius: never behind the own-pixel z-buffer
    assert (syn.view.depth[rows, cols] <= zbuf[rows, cols] + 1e-5).all() and (syn.view.depth[rows, cols] > 0).all()


def test_several_views_render_into_one_z_buffer(trained):
    views = [make_view(seed=1, size=64), make_view(seed=5, size=64, pose=Pose(0.3, 0.2, 0.15))]
    target = Pose(0.1, 0.1, 0.05)
    out = trained.synthesize_from(views, target)
    assert len(out) == 2 and out[0].view is out[1].view
    camera = views[0].camera
    moved = []
    for view in views:
        T = target.relative_to(view.pose)
        uv, z = camera.project(camera.unproject(trained.predict_depth(view)).reshape(-1, 3) @ T[:3, :3].T + T[:3, 3])
        moved.append((uv, z, camera.contains(uv)))
    zbuf = np.full(camera.shape, np.inf)
    for uv, z, inside in moved:  # one z-buffer over both views' points, at their nearest pixels
        np.minimum.at(zbuf, (np.rint(uv[inside, 1]).astype(int), np.rint(uv[inside, 0]).astype(int)), z[inside])
    for (uv, z, inside), syn in zip(moved, out, strict=True):
        front = np.zeros_like(inside)
        front[inside] = z[inside] <= zbuf[np.rint(uv[inside, 1]).astype(int), np.rint(uv[inside, 0]).astype(int)] * 1.02
        np.testing.assert_array_equal(syn.visible.reshape(-1), front)
        assert 0.05 < front.mean() < 0.95  # each view is partly hidden by the other's points


def test_random_weights_are_the_same_in_every_instance_and_after_pickling():
    view = make_view(size=64)
    a = SynSinSynthesizer(RANDOM).synthesize(view, Pose(0.2, 0.0, 0.0)).view.rgb
    copy = pickle.loads(pickle.dumps(SynSinSynthesizer(RANDOM)))
    np.testing.assert_array_equal(copy.synthesize(view, Pose(0.2, 0.0, 0.0)).view.rgb, a)


def test_random_weights_caveat_reaches_the_variant_label(ssga_installed_registry):
    def label(synthesizer: dict) -> str:
        config = {
            "variants": ["SPD"],
            "stages": {
                "parser": {"name": "slico"},
                "descriptor": {"name": "dense-sift"},
                "synthesizer": {"name": "synsin", **synthesizer},
            },
        }
        return validate_experiment(config, ssga_installed_registry).variants[0].label

    assert label({"weights": "random"}).endswith("[random weights]")
    assert "random" not in label({})
    assert SynSinSynthesizer.caveat(RANDOM) == "random weights" and SynSinSynthesizer.caveat(TRAINED) == ""


def test_config_is_validated():
    assert SynSinConfig() == SynSinConfig(
        weights=LIGHT_WEIGHTS, network=None, radius=None, points_per_pixel=None, depth_tolerance=0.02, device="auto"
    )
    for bad in (
        {"radius": 0.0},
        {"radius": 20.0},
        {"points_per_pixel": 0},
        {"network": "vgg"},
        {"depth_tolerance": 0.0},
        {"K": 8},
    ):
        with pytest.raises(ValidationError):
            SynSinConfig(**bad)
    for name, params in SynSinSynthesizer.presets.items():
        assert SynSinConfig(**params), name
    assert all(field.description for field in SynSinConfig.model_fields.values())


def test_radius_and_k_override_the_files(trained):
    assert (trained.options.radius, trained.options.points_per_pixel) == (1.5, 8)
    wide = SynSinSynthesizer(SynSinConfig(device="cpu", radius=3.0, points_per_pixel=16))
    assert (wide.options.radius, wide.options.points_per_pixel) == (3.0, 16) and wide.net is trained.net


def test_a_missing_file_is_one_line_naming_the_field_and_the_file(tmp_path):
    one_line_checkpoint_error(
        lambda: SynSinSynthesizer(SynSinConfig(weights=str(tmp_path / "absent.pth"))), "'weights'", "absent.pth", "synthesizer 'synsin'"
    )


def test_unreadable_files_are_one_line(tmp_path):
    (tmp_path / "corrupt.pth").write_bytes(b"\x80\x02 not a checkpoint")
    (tmp_path / "noise.pth").write_bytes(np.random.default_rng(0).integers(0, 256, 4096, dtype=np.uint8).tobytes())
    whole = (WEIGHTS_DIR / LIGHT_WEIGHTS).read_bytes()
    (tmp_path / "truncated.pt").write_bytes(whole[: len(whole) // 2])
    for name in ("corrupt.pth", "noise.pth", "truncated.pt"):
        for network in (None, "synsin"):
            with pytest.raises(CheckpointError, match=f"{name} is not a readable checkpoint") as err:
                SynSinSynthesizer(SynSinConfig(weights=str(tmp_path / name), network=network))
            assert "\n" not in str(err.value) and "'weights'" in str(err.value)


def test_a_light_file_alone_names_its_network(tmp_path, trained):
    assert trained.config.network == "light" and SynSinConfig().network is None  # the packaged weights
    assert pickle.loads(pickle.dumps(trained)).config.network == "light"
    assert SynSinSynthesizer(RANDOM).config.network == "light"
    assert SynSinSynthesizer(SynSinConfig(weights="random", network="synsin", device="cpu")).config.network == "synsin"
    narrow = LightOptions(depth_widths=(8, 16, 16, 16, 16))
    path = tmp_path / "narrow.pt"  # the widths come with the file, in its opts
    path.write_bytes(checkpoint_bytes({"state_dict": SynSinLight(narrow).state_dict(), "opts": narrow.to_json()}))
    s = SynSinSynthesizer(SynSinConfig(weights=str(path), device="cpu"))
    assert s.config.network == "light" and s.net.light == narrow


def test_mismatched_files_are_one_line(tmp_path):
    narrow = SynSinLight(LightOptions(depth_widths=(8, 16, 16, 16, 16)))
    path = tmp_path / "narrow.pt"
    path.write_bytes(checkpoint_bytes({"state_dict": narrow.state_dict()}))  # opts missing: read as the default widths
    message = one_line_checkpoint_error(
        lambda: SynSinSynthesizer(SynSinConfig(weights=str(path))), "'weights'", "narrow.pt matches none of the layouts it loads ('light', 'synsin')"
    )
    assert "closest: 'light': " in message and "wrong shape: pts_regressor.inc.weight (8, 5, 3, 3) (expected (16, 5, 3, 3))" in message
    path.write_bytes(checkpoint_bytes({"state_dict": SynSinLight().state_dict(), "opts": LightOptions().to_json()}))
    message = one_line_checkpoint_error(
        lambda: SynSinSynthesizer(SynSinConfig(weights=str(path), network="synsin")),  # a light file read as the official model
        "config field network = 'synsin' contradicts config field 'weights'",
    )
    assert "narrow.pt holds the 'light' layout (trained here on procedural homes" in message
    state = SynSinLight().state_dict()
    state["projector.extra.weight"] = torch.zeros(1)
    del state["encoder.0.bias"]
    path.write_bytes(checkpoint_bytes({"state_dict": state, "opts": LightOptions().to_json()}))
    with pytest.raises(CheckpointError, match=r"closest: 'light': 1 missing: encoder.0.bias; 1 unexpected: projector.extra.weight"):
        SynSinSynthesizer(SynSinConfig(weights=str(path)))
    path.write_bytes(checkpoint_bytes({"conv1.weight": torch.zeros(64, 3, 7, 7), "fc.weight": torch.zeros(10, 512)}))  # another model
    with pytest.raises(CheckpointError, match=r"matches none of the layouts .* closest: 'light': \d+ missing: pts_regressor.inc.weight"):
        SynSinSynthesizer(SynSinConfig(weights=str(path)))
    path.write_bytes(checkpoint_bytes({"state_dict": SynSinLight().state_dict(), "opts": {"depth_widths": [1]}}))
    with pytest.raises(CheckpointError, match="unreadable 'opts'"):
        SynSinSynthesizer(SynSinConfig(weights=str(path)))


def test_the_packaged_weights_carry_their_provenance():
    provenance = packaged_provenance(WEIGHTS_DIR / LIGHT_WEIGHTS, "ssga_synthesizer_synsin.train")
    assert min(provenance["train_seeds"]) >= 3000 and not set(provenance["train_seeds"]) & set(provenance["heldout_seeds"])
    heldout = provenance["figures"]["heldout"]
    trained, init = heldout["trained"]["scores"]["synsin"], heldout["init"]["scores"]["synsin"]
    assert trained["seen_psnr"] > init["seen_psnr"] and trained["image_psnr"] > init["image_psnr"]
    assert heldout["trained"]["depth"]["median_abs_rel"] < heldout["init"]["depth"]["median_abs_rel"]


def test_other_cameras_and_sizes_work():
    camera = Camera(width=72, height=40, hfov_deg=70.0)
    rgb = np.random.default_rng(0).integers(0, 256, (40, 72, 3), dtype=np.uint8)
    view = View(rgb=rgb, pose=Pose(0.0, 0.0, 0.0), camera=camera)
    syn = SynSinSynthesizer(RANDOM).synthesize(view, Pose(0.0, 0.0, 0.1))
    assert syn.view.rgb.shape == (40, 72, 3) and syn.target_uv.shape == (40, 72, 2)


def test_runs_on_the_cpu_and_on_cuda_alike():
    view = make_view(size=64)
    target = Pose(0.2, 0.0, 0.1)
    a = SynSinSynthesizer(SynSinConfig(device="cpu")).synthesize(view, target)
    if not torch.cuda.is_available():
        with pytest.raises(InputError, match="no CUDA device"):
            SynSinSynthesizer(SynSinConfig(device="cuda"))
        return
    b = SynSinSynthesizer(SynSinConfig(device="cuda")).synthesize(view, target)
    np.testing.assert_allclose(a.target_uv, b.target_uv, atol=1e-2)
    assert np.abs(a.view.rgb.astype(int) - b.view.rgb).mean() < 2.0
