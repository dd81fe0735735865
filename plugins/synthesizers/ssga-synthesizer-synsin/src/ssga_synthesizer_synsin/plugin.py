"""The ``synsin`` synthesizer: SynSin-style learned view synthesis from RGB alone (paper §3.1.3, Fig. 3).

For each source view the network predicts a metric depth and per-pixel features
(:mod:`.model`); the core's geometry (``Camera.unproject``, ``Pose.relative_to``,
``Camera.project``) moves every pixel to the target pose, which gives the point map;
the points are splatted, z-buffered and alpha-composited with a soft radius
(:mod:`.splat`), and the refinement network turns the splatted features into the
target image. Several views render jointly: their points share one z-buffer and one
refinement pass.

Weights: the light network trained here on procedural homes the benchmark never shows
(``weights/synsin-light.pt``; how it was made: the README and
``weights/synsin-light.json``), or SynSin's released MP3D model (``weights =
"mp3d/synsin.pth"``, which the user downloads; preset ``mp3d``). A file names its own
network: its keys and shapes say which (:data:`LAYOUTS`).
"""

from __future__ import annotations

import argparse
import dataclasses
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
from pydantic import Field

from ssga_bench import (
    Layout, Learned, LearnedConfig, load_checkpoint, load_strict, meta_shapes, network_field, read_layout, seeded,
    tensor_state, weights_field,
)
from ssga_core import CheckpointError, Data, InputError, Pose, Synthesis, Synthesizer, View, hookimpl

if TYPE_CHECKING:  # torch and the networks load when a synthesizer is made, not when the plugin registers
    import torch

    from ssga_synthesizer_synsin.model import RenderOptions

WEIGHTS_DIR = Path(__file__).parent / "weights"
"""Where relative ``weights`` are looked up first (then the working directory)."""

LIGHT_WEIGHTS = "synsin-light.pt"
"""The packaged light network's file in :data:`WEIGHTS_DIR`."""

OFFICIAL_WEIGHTS = "mp3d/synsin.pth"
"""SynSin's MP3D checkpoint, as its ``download_models.sh`` lays it out (not shipped)."""

LAYOUTS = (
    Layout("light", f"trained here on procedural homes: weights/{LIGHT_WEIGHTS}, the default"),
    Layout("synsin", f"SynSin's released MP3D model (facebookresearch/synsin, download_models.sh): {OFFICIAL_WEIGHTS}"),
)
"""The networks a ``weights`` file can hold; which one, the file's keys and shapes say."""


RANDOM_NETWORK = "light"
"""The network random weights build (tests only), where the config leaves it out."""


class SynSinConfig(LearnedConfig):
    """Which network renders, and how its points are splatted."""

    weights: str = weights_field(LIGHT_WEIGHTS, "SynSin's 'mp3d/synsin.pth'")
    network: Literal["light", "synsin"] | None = network_field(
        "'light' (this package's network, 0.6 M parameters, the packaged weights) or 'synsin' (the official "
        "MP3D model's layout: ResNet encoder and decoder of width 64, 32-filter depth U-Net)."
    )
    radius: float | None = Field(
        default=None,
        gt=0.0,
        le=16.0,
        description="Splat radius in pixels; None: the one the weights were trained with (the light file's: 1.5; "
        "SynSin's opts: 4).",
    )
    points_per_pixel: int | None = Field(
        default=None,
        ge=1,
        le=512,
        description="K, the nearest points each pixel composites; None: the weights' own (light: 8; SynSin: 128).",
    )
    depth_tolerance: float = Field(
        default=0.02,
        gt=0.0,
        le=1.0,
        description="A source pixel is visible when its depth is within this (relative) of the nearest point landing "
        "on its target pixel (the depth-warp synthesizer's tolerance).",
    )


EXPECTED = (
    "a SynSin checkpoint ({'state_dict', 'opts'}) of the light network (pts_regressor.*, encoder.*, projector.*) "
    "or of SynSin's MP3D model (model.module.*: resnet_256W8UpDown64, ngf 64)"
)
"""What a ``weights`` file should hold, as errors say it."""



class SynSinSynthesizer(Learned, Synthesizer):
    """Learned novel-view synthesis from one RGB image (or several, jointly); see the module docstring."""

    name = "synsin"
    abbrev = "SS"
    Config = SynSinConfig
    reloaded = ("net",)
    layouts = LAYOUTS
    packaged_weights = WEIGHTS_DIR
    trained_on = "procedural"  # the workspace source whose homes the packaged weights saw
    consumes = frozenset({Data.RGB})
    produces = frozenset({Data.RGB, Data.DEPTH, Data.POINT_MAP})
    presets = {
        "light": {},
        "mp3d": {"weights": OFFICIAL_WEIGHTS},
    }

    @property
    def options(self) -> RenderOptions:
        """The renderer settings: the network's, with the config's overrides."""
        cfg: SynSinConfig = self.config  # type: ignore[assignment]
        base: RenderOptions = self.net.options  # type: ignore[assignment]
        changes = {k: v for k, v in (("radius", cfg.radius), ("points_per_pixel", cfg.points_per_pixel)) if v is not None}
        return dataclasses.replace(base, **changes)

    # ------------------------------------------------------------------ loading

    def _load(self) -> torch.nn.Module:
        """The network, once per process per file; ``self.config`` gets the file's ``network``."""
        cfg: SynSinConfig = self.config  # type: ignore[assignment]
        net, _ = self.load_network((cfg.network,), self._random, self._from_file)
        return net

    def _random(self) -> tuple[torch.nn.Module, dict[str, Any]]:
        cfg: SynSinConfig = self.config  # type: ignore[assignment]
        fields = {"network": cfg.network or RANDOM_NETWORK}
        return seeded(lambda: self._network(fields["network"], None)), fields

    def _from_file(self, path: Path) -> tuple[torch.nn.Module, dict[str, Any]]:
        import torch

        from ssga_synthesizer_synsin.official import SynSin, official_state_dict

        cfg: SynSinConfig = self.config  # type: ignore[assignment]
        # SynSin pickles its options as an argparse.Namespace, which weights_only loading refuses unless allowed.
        with torch.serialization.safe_globals([argparse.Namespace]):
            checkpoint = load_checkpoint(path, self.who, EXPECTED)
        opts = checkpoint.get("opts") if isinstance(checkpoint, dict) else None
        state = checkpoint.get("state_dict", checkpoint) if isinstance(checkpoint, dict) else checkpoint
        state = tensor_state(state, self.who, path, EXPECTED)
        # Both layouts are compared in this package's key space, which SynSin's strict load needs anyway: its
        # wrapper prefix, training-only modules and spectral norm mapped away (a light file passes unchanged).
        state, _ = official_state_dict(state, meta_shapes(SynSin))
        _, fields = read_layout(cfg, state, LAYOUTS, lambda layout, _: self._network_of(layout, opts, path), self.who, path)
        net = self._network(fields["network"], opts, path)
        load_strict(net, state, self.who, path, EXPECTED)
        return net, fields

    def _network_of(self, layout: Layout, opts: Any, path: Path) -> tuple[dict[str, Any], dict[str, tuple[int, ...]]]:
        """The fields and keys and shapes of ``layout``'s network with the file's options."""
        return {"network": layout.name}, meta_shapes(lambda: self._network(layout.name, opts, path))

    def _network(self, name: str, opts: Any, path: Path | None = None) -> torch.nn.Module:
        """The ``name`` network with a file's ``opts``: the light network's widths and renderer (a dict, as it
        saves them; none: the defaults), SynSin's renderer (its ``argparse.Namespace``)."""
        from ssga_synthesizer_synsin.model import LightOptions, SynSinLight
        from ssga_synthesizer_synsin.official import SynSin, options_from_opts

        if name != "light":
            return SynSin(options_from_opts(opts))
        try:
            return SynSinLight(LightOptions.from_json(opts) if isinstance(opts, dict) else LightOptions())
        except (KeyError, TypeError, ValueError) as exc:
            raise CheckpointError(
                f"{self.who}: config field 'weights': {path} has unreadable 'opts' ({exc!r}); expected {EXPECTED}"
            ) from None

    # ------------------------------------------------------------------ synthesis

    def _synthesize(self, view: View, target: Pose) -> Synthesis:
        return self._synthesize_from([view], target)[0]

    def _synthesize_from(self, views: Sequence[View], target: Pose) -> list[Synthesis]:
        """All the views' points in one z-buffer and one refinement, seen by the first view's camera at ``target``."""
        import torch

        from ssga_synthesizer_synsin.model import normalise, to_uint8
        from ssga_synthesizer_synsin.splat import splat

        cfg: SynSinConfig = self.config  # type: ignore[assignment]
        camera = views[0].camera
        h, w = camera.shape
        options = self.options
        device = self.device
        uvs, zs, feats, depths = [], [], [], []
        with torch.inference_mode():
            for view in views:
                img = normalise(view.rgb).to(device)
                depth = self.net.depth(img)  # type: ignore[operator]
                feats.append(self.net.features(img).flatten(2).transpose(1, 2)[0])  # type: ignore[operator]
                d = depth[0, 0].float().cpu().numpy()
                depths.append(d)
                uv, z = _move(view, d, target, camera)
                uvs.append(uv.reshape(-1, 2))
                zs.append(z.reshape(-1))
            uv_t = torch.from_numpy(np.concatenate(uvs)).to(device)[None]
            z_t = torch.from_numpy(np.concatenate(zs)).to(device)[None]
            s = splat(
                uv_t, z_t, torch.cat(feats)[None], (h, w),
                radius=options.radius, points_per_pixel=options.points_per_pixel, tau=options.tau, rad_pow=options.rad_pow,
            )  # fmt: skip
            rgb = to_uint8(self.net.refine(s))[0]  # type: ignore[operator]
            nearest = s.nearest[0].cpu().numpy()
            synthetic_depth = s.depth[0].float().cpu().numpy()
        synthetic = View(rgb=rgb, pose=target, camera=camera, depth=synthetic_depth.astype(np.float32), synthetic=True)
        out, start = [], 0
        for view, uv, z in zip(views, uvs, zs, strict=True):
            n = len(z)
            near = nearest[start : start + n]
            start += n
            with np.errstate(invalid="ignore"):
                visible = camera.contains(uv) & np.isfinite(near) & (z <= near * (1.0 + cfg.depth_tolerance))
            sh, sw = view.camera.shape
            out.append(Synthesis(view=synthetic, target_uv=uv.reshape(sh, sw, 2), visible=visible.reshape(sh, sw)))
        return out

    def predict_depth(self, view: View) -> np.ndarray:
        """``(H, W)`` float32 metric depth the network predicts for ``view``."""
        import torch

        from ssga_synthesizer_synsin.model import normalise

        with torch.inference_mode():
            return self.net.depth(normalise(view.rgb).to(self.device))[0, 0].float().cpu().numpy()  # type: ignore[operator]


def _move(view: View, depth: np.ndarray, target: Pose, camera) -> tuple[np.ndarray, np.ndarray]:
    """Each pixel of ``view`` at ``depth`` in ``camera`` at ``target``: ``(H*W, 2)`` uv (NaN behind it) and ``(H*W,)`` depths."""
    if depth.shape != view.camera.shape:
        raise InputError(f"synthesizer 'synsin': depth of shape {depth.shape} for a {view.camera.shape} view")
    T = target.relative_to(view.pose).astype(np.float32)
    points = view.camera.unproject(depth) @ T[:3, :3].T + T[:3, 3]
    uv, z = camera.project(points.reshape(-1, 3))
    return uv.astype(np.float32), z.astype(np.float32)


@hookimpl
def ssga_register_synthesizers() -> list[type[Synthesizer]]:
    return [SynSinSynthesizer]
