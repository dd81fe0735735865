"""The ``midas-warp`` synthesizer: depth-warp on metric depth estimated from RGB alone by MiDaS.

For each source view MiDaS (:mod:`.model`) predicts relative inverse depth, the
calibration stored beside the weights (:mod:`.calibration`) turns it into metric depth
(clamped to ``depth_range``), and :class:`ssga_synthesizer_depth_warp.plugin.DepthWarp`,
whose every option this config inherits, renders the target pose. The view's own
depth, if it has one, is never read: views without depth synthesize. The synthetic
view carries the metric depth it was rendered with, so several views fuse.

Weights: the default is the light network trained here on procedural homes the
benchmark never shows (``weights/midas-light.pt``, calibrated in
``weights/midas-light.calibration.json``; how both were made: the README and
``weights/midas-light.json``). The official MiDaS v2.1 small file, which the user places
and calibrates (``python -m ssga_synthesizer_midas_warp.calibrate``), loads by itself
(``weights = "midas_v21_small_256.pt"``; preset ``v21-small``): its keys and shapes say
its network (:data:`LAYOUTS`).
"""

from __future__ import annotations

import threading
import weakref
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Literal

import numpy as np
from pydantic import Field, model_validator

from ssga_core import Data, Pose, Synthesis, Synthesizer, View, hookimpl
from ssga_bench import (
    RANDOM_SEED, Layout, Learned, LearnedConfig, file_stamp, load_checkpoint, load_strict, meta_shapes,
    network_field, read_layout, tensor_state, weights_field,
)
from ssga_synthesizer_depth_warp.plugin import DepthWarp, DepthWarpConfig
from ssga_synthesizer_midas_warp.calibration import Calibration, calibration_path, minmax_depth, sha256_file

WEIGHTS_DIR = Path(__file__).parent / "weights"
"""Where relative ``weights`` and ``calibration`` paths are looked up first (then the working directory)."""

LIGHT_WEIGHTS = "midas-light.pt"
"""The packaged light network's file in :data:`WEIGHTS_DIR`."""


AUTO, MINMAX = "auto", "minmax"

OFFICIAL_WEIGHTS = "midas_v21_small_256.pt"
"""MiDaS v2.1 small's release file, as isl-org/MiDaS names it (not shipped)."""

LAYOUTS = (
    Layout("light", f"trained here on procedural homes: weights/{LIGHT_WEIGHTS}, the default"),
    Layout("v21-small", f"the official MiDaS v2.1 small release (isl-org/MiDaS, v2_1): {OFFICIAL_WEIGHTS}"),
)
"""The networks a ``weights`` file can hold; which one, the file's keys and shapes say."""

RANDOM_NETWORK = "light"
"""The network random weights build (tests only), where the config leaves it out."""


class MidasWarpConfig(DepthWarpConfig, LearnedConfig):
    """MiDaS's network, weights and calibration; the warp's fields are depth-warp's."""

    weights: str = weights_field(LIGHT_WEIGHTS, "the official 'midas_v21_small_256.pt'")
    network: Literal["light", "v21-small"] | None = network_field(
        "'light': the narrow MiDaS-small trained here (the packaged weights); 'v21-small': MiDaS v2.1 small "
        "(EfficientNet-Lite3, 64 features), the official file's layout."
    )
    calibration: str = Field(
        default=AUTO,
        min_length=1,
        description="How relative inverse depth becomes metric: 'auto' reads <weights stem>.calibration.json beside the "
        "weights (fitted offline on procedural homes; random weights use 'minmax'); a path names a calibration file "
        "(relative: the weights/ folder, then the working directory); 'minmax' spreads each image's prediction over "
        "depth_range (no calibration, no scale: a fallback).",
    )
    depth_range: tuple[float, float] = Field(
        default=(0.2, 20.0),
        description="Estimated depths are clamped to [near, far] metres (inverse depths at or below 1 / far become far).",
    )

    @model_validator(mode="after")
    def _range_is_sane(self) -> MidasWarpConfig:
        near, far = self.depth_range
        if not 0.0 < near < far:
            raise ValueError(f"depth_range must be 0 < near < far, got {self.depth_range}")
        return self


class MidasWarp(Learned, DepthWarp):
    """Estimates each view's metric depth with MiDaS, then warps it as depth-warp does.

    The network loads when the synthesizer is made (a bad ``weights`` or ``calibration``
    file is reported before any work), once per process for every instance that uses the
    same file. Each real view's depth is estimated once and cached for as long as the
    ``View`` object lives (the pipeline renders one view at many targets).
    """

    name = "midas-warp"
    abbrev = "MW"
    Config = MidasWarpConfig
    consumes = frozenset({Data.RGB})
    produces = frozenset({Data.RGB, Data.DEPTH, Data.POINT_MAP})
    layouts = LAYOUTS
    packaged_weights = WEIGHTS_DIR
    trained_on = "procedural"  # the workspace source whose homes the packaged weights saw
    presets = {
        **DepthWarp.presets,
        "light": {},
        "v21-small": {"weights": OFFICIAL_WEIGHTS},
    }

    def __init__(self, config: MidasWarpConfig | None = None) -> None:
        super().__init__(config)
        self.net, self.calibration = self._load()
        self._estimated: weakref.WeakKeyDictionary[View, View] = weakref.WeakKeyDictionary()
        self._estimate_lock = threading.Lock()

    # ------------------------------------------------------------------ loading

    def _load(self) -> tuple[Any, Calibration | None]:
        """The network, once per process per file, and its calibration; ``self.config`` gets the file's ``network``
        first, which the calibration is checked against."""
        cfg: MidasWarpConfig = self.config  # type: ignore[assignment]
        net, path = self.load_network((cfg.network,), self._random, self._from_file)
        sha = "" if path is None else self.once_per_process(("sha256", file_stamp(path)), lambda: sha256_file(path))
        return net, self._calibration(path, sha)

    def _random(self) -> tuple[Any, dict[str, Any]]:
        """The training's seeded initialisation: the same in every process, its output positive and varied."""
        from ssga_synthesizer_midas_warp.model import NETWORKS, MidasNet, init_weights

        cfg: MidasWarpConfig = self.config  # type: ignore[assignment]
        fields = {"network": cfg.network or RANDOM_NETWORK}
        return init_weights(MidasNet(NETWORKS[fields["network"]]), RANDOM_SEED), fields

    def _from_file(self, path: Path) -> tuple[Any, dict[str, Any]]:
        from ssga_synthesizer_midas_warp.model import NETWORKS, MidasNet

        cfg: MidasWarpConfig = self.config  # type: ignore[assignment]
        expected = (
            "a MiDaS-small state dict (pretrained.*, scratch.*) of the 'light' or 'v21-small' network, "
            "plain or under 'state_dict' or 'model'"
        )
        checkpoint = load_checkpoint(path, self.who, expected)
        state = tensor_state(_unwrapped(checkpoint), self.who, path, expected)
        _, fields = read_layout(cfg, state, LAYOUTS, self._network_of, self.who, path)
        net = MidasNet(NETWORKS[fields["network"]])
        load_strict(net, state, self.who, path, expected)
        return net, fields

    def _network_of(self, layout: Layout, state: Any) -> tuple[dict[str, Any], dict[str, tuple[int, ...]]]:
        """The fields and keys and shapes of ``layout``'s network (MiDaS-small has no size to read from the file)."""
        from ssga_synthesizer_midas_warp.model import NETWORKS, MidasNet

        return {"network": layout.name}, meta_shapes(lambda: MidasNet(NETWORKS[layout.name]))

    def _calibration(self, weights: Path | None, sha: str) -> Calibration | None:
        """The calibration to use, or ``None`` for the per-image min/max prior."""
        cfg: MidasWarpConfig = self.config  # type: ignore[assignment]
        if cfg.calibration == MINMAX or (cfg.calibration == AUTO and weights is None):
            return None
        if cfg.calibration == AUTO:
            assert weights is not None
            path = calibration_path(weights)
        else:
            path = Path(cfg.calibration).expanduser()
            if not path.is_absolute():
                path = next((p for p in (WEIGHTS_DIR / path, Path.cwd() / path) if p.is_file()), Path.cwd() / path)
        calibration = Calibration.read(path, self.who)
        if weights is None:  # random weights with an explicit calibration file: nothing to check it against
            return calibration
        return calibration.check(cfg.network, sha, path, self.who)

    # ------------------------------------------------------------------ depth

    def predict(self, images: Sequence[np.ndarray]) -> np.ndarray:
        """MiDaS's relative inverse depth ``(N, H, W)`` of same-sized uint8 RGB images."""
        from ssga_synthesizer_midas_warp.model import predict

        return predict(self.net, images, self.device)

    def estimate_depth(self, images: Sequence[np.ndarray]) -> np.ndarray:
        """Metric planar depth ``(N, H, W)`` float32 of same-sized uint8 RGB images, within ``depth_range``."""
        cfg: MidasWarpConfig = self.config  # type: ignore[assignment]
        pred = self.predict(images)
        if self.calibration is None:
            return minmax_depth(pred, cfg.depth_range)
        return self.calibration.depth(pred, cfg.depth_range)

    def with_depth(self, views: Sequence[View]) -> list[View]:
        """Each view with its estimated depth in place of any it had (cached per ``View`` object)."""
        with self._estimate_lock:
            out: list[View | None] = [self._estimated.get(v) for v in views]
        todo: dict[tuple[int, int], list[int]] = {}
        for i, (view, done) in enumerate(zip(views, out)):
            if done is None:
                todo.setdefault(view.camera.shape, []).append(i)
        for indices in todo.values():  # one network batch per image size
            depth = self.estimate_depth([views[i].rgb for i in indices])
            for i, d in zip(indices, depth):
                v = views[i]
                out[i] = View(rgb=v.rgb, pose=v.pose, camera=v.camera, depth=d, semantic=v.semantic, instance=v.instance, synthetic=v.synthetic)
                with self._estimate_lock:
                    self._estimated[v] = out[i]  # type: ignore[assignment]
        return out  # type: ignore[return-value]

    # ------------------------------------------------------------------ synthesis

    def _synthesize(self, view: View, target: Pose) -> Synthesis:
        return self._synthesize_from([view], target)[0]

    def _synthesize_from(self, views: Sequence[View], target: Pose) -> list[Synthesis]:
        """depth-warp's joint render of the views with their estimated depth."""
        return super()._synthesize_from(self.with_depth(views), target)


def _unwrapped(checkpoint: Any) -> Any:
    """The state dict in ``checkpoint``: plain, or under 'state_dict' (ours) or 'model' (MiDaS's training format
    ``{'model', 'optimizer'}``)."""
    if isinstance(checkpoint, dict):
        for wrapper in ("state_dict", "model"):
            if isinstance(checkpoint.get(wrapper), dict):
                return checkpoint[wrapper]
    return checkpoint


@hookimpl
def ssga_register_synthesizers() -> list[type[Synthesizer]]:
    return [MidasWarp]
