"""Semantic segmentation as scene-graph parts: the paper's cascade segmentation parser (P-SE, §3.1.1).

CSAIL's ADE20K scene-parsing network (:mod:`.model`: a dilated deep-stem ResNet and
the PPM decoder, as ``mit_semseg`` builds them) labels every pixel with a class; each
connected piece of one class of at least ``min_region_px`` pixels becomes a region,
with the class index in ``Regions.categories``, its name in ``Regions.names`` and the
mean probability of that class over the piece in ``Regions.scores``. Edges are the
core's business (box proximity), as for every parser.

Weights: ``weights`` names a *folder* holding ``encoder_epoch_20.pth`` and
``decoder_epoch_20.pth``, as CSAIL's releases are laid out. The default is the light
network trained here on procedural homes the benchmark never shows
(``weights/procedural-light-ppm_deepsup/``; how it was made: the README and the
``provenance.json`` beside the files); the presets ``ade20k-resnet50dilated-ppm_deepsup``
and ``ade20k-resnet18dilated-ppm_deepsup`` select the official releases, whose folders
the user places.
"""

from __future__ import annotations

import difflib
import threading
from collections.abc import Sequence
from pathlib import Path
from typing import Annotated, Any, Literal, Self

import numpy as np
from pydantic import Field, model_validator

from ssga_core import CheckpointError, Data, InputError, MissingWeightsError, Parser, Regions, View, boxes_from_labels, hookimpl
from ssga_bench import RANDOM_WEIGHTS, Learned, LearnedConfig, load_checkpoint, load_strict, network_calls
from ssga_parser_cascade_seg.classes import VOCABULARIES

WEIGHTS_DIR = Path(__file__).parent / "weights"
"""Where relative ``weights`` folders are looked up first (then the working directory)."""

LIGHT_WEIGHTS = "procedural-light-ppm_deepsup"
"""The packaged light network's folder in :data:`WEIGHTS_DIR`."""

FILES = {"encoder": "encoder_epoch_20.pth", "decoder": "decoder_epoch_20.pth"}
"""A release folder's files (CSAIL's ``demo_test.sh``)."""

ORIGINAL_SCALES = (300, 375, 450, 525, 600)
"""CSAIL's test scales (shorter side, ``DATASET.imgSizes``) for the official releases."""

LIGHT_SCALES = (176, 216, 256, 296, 336)
"""The same ratios around the light network's 256-pixel views: its multi-scale setting."""

RANDOM_SEED = 0
"""Random weights are :func:`~.model.init_weights` with this seed: the same in every process."""



class CascadeSegConfig(LearnedConfig):
    weights: str = Field(
        default=LIGHT_WEIGHTS,
        min_length=1,
        description="Folder holding encoder_epoch_20.pth and decoder_epoch_20.pth, as CSAIL's releases are laid out "
        "(relative: the plugin's weights/ folder, then the working directory): the light network trained here "
        "(default), e.g. 'ade20k-resnet50dilated-ppm_deepsup' (network = 'resnet50dilated', classes = 'ade20k'), "
        "or 'random' (tests only).",
    )
    network: Literal["light", "resnet18dilated", "resnet50dilated"] = Field(
        default="light",
        description="Encoder layout (decoder: PPM with deep supervision): 'light' (ResNet18-dilated at a quarter "
        "of its widths, the packaged weights), or the official 'resnet18dilated' (fc_dim 512) or "
        "'resnet50dilated' (fc_dim 2048). Must match the weights.",
    )
    classes: Literal["procedural", "ade20k"] = Field(
        default="procedural",
        description="The vocabulary the weights predict: 'procedural' (13 categories of procedural homes, the "
        "packaged weights) or 'ade20k' (ADE20K's 150, the official releases). Must match the weights.",
    )
    image_sizes: tuple[Annotated[int, Field(ge=8, le=4096)], ...] = Field(
        default=(256,),
        min_length=1,
        max_length=16,
        description="Shorter image side at each test scale; the class probabilities are averaged over the scales "
        "(CSAIL's test: 300, 375, 450, 525, 600). One size: single-scale.",
    )
    max_size: int = Field(default=1000, ge=8, le=8192, description="No scale makes the longer side exceed this (CSAIL's imgMaxSize).")
    padding: int = Field(
        default=8,
        ge=1,
        le=64,
        description="Each scaled side is rounded up to a multiple of this (the network's output stride; CSAIL's padding_constant).",
    )
    min_region_px: int = Field(
        default=64,
        ge=0,
        le=1 << 24,
        description="Connected pieces of one class smaller than this many pixels get no region (left out, not "
        "merged: merging would join different classes). 0 keeps every piece.",
    )
    connectivity: Literal[4, 8] = Field(default=8, description="Pixels of one class join a piece through 4 or 8 neighbours.")
    ignore_classes: tuple[str, ...] = Field(
        default=(),
        max_length=256,
        description="Class names (of the vocabulary in 'classes') whose pixels get no region, e.g. wall, floor, ceiling.",
    )
    drop_holes: bool = Field(
        default=True,
        description="In a synthetic view with depth, pixels the synthesizer left empty (no depth) get no region, so "
        "the holes do not become parts of the graph.",
    )

    @model_validator(mode="after")
    def _known_classes(self) -> Self:
        names = VOCABULARIES[self.classes]
        for name in self.ignore_classes:
            if name not in names:
                close = difflib.get_close_matches(name, names, n=3)
                hint = f"; did you mean {', '.join(map(repr, close))}?" if close else ""
                raise ValueError(f"ignore_classes: {name!r} is no class of classes = {self.classes!r}{hint}")
        return self


_NETWORKS: dict[tuple[Any, ...], Any] = {}
_LOCK = threading.Lock()


class CascadeSeg(Learned, Parser):
    """One region per connected piece of each predicted class (class index, name and mean probability per region).

    The network loads when the parser is made (a bad ``weights`` folder is reported
    before any work), once per process for every instance that uses the same files.
    """

    name = "cascade-seg"
    abbrev = "SE"  # the paper's tables: "P-SE (PDS)"
    Config = CascadeSegConfig
    reloaded = ("net",)
    consumes = frozenset({Data.RGB})
    presets = {
        "light": {},
        "light-multiscale": {"image_sizes": LIGHT_SCALES},
        "ade20k-resnet18dilated-ppm_deepsup": {
            "network": "resnet18dilated",
            "classes": "ade20k",
            "weights": "ade20k-resnet18dilated-ppm_deepsup",
            "image_sizes": ORIGINAL_SCALES,
        },
        "ade20k-resnet50dilated-ppm_deepsup": {
            "network": "resnet50dilated",
            "classes": "ade20k",
            "weights": "ade20k-resnet50dilated-ppm_deepsup",
            "image_sizes": ORIGINAL_SCALES,
        },
    }

    def __init__(self, config: CascadeSegConfig | None = None) -> None:
        super().__init__(config)
        cfg: CascadeSegConfig = self.config  # type: ignore[assignment]
        self.class_names: tuple[str, ...] = VOCABULARIES[cfg.classes]
        self._ignored = np.array([self.class_names.index(n) for n in cfg.ignore_classes], dtype=np.int64)
        self.net = self._load()

    @property
    def who(self) -> str:
        return f"{self.kind} {self.name!r}"

    # ------------------------------------------------------------------ loading

    def weights_folder(self) -> Path:
        """The release folder ``config.weights`` names, holding both files (looked up in :data:`WEIGHTS_DIR` first)."""
        value = self.config.weights
        path = Path(value).expanduser()
        candidates = [path] if path.is_absolute() else [WEIGHTS_DIR / path, Path.cwd() / path]
        wanted = f"the folder holding {FILES['encoder']} and {FILES['decoder']}, as CSAIL's releases are laid out"
        for folder in candidates:
            if folder.is_file():
                raise MissingWeightsError(f"{self.who}: config field 'weights' = {value!r}: {folder} is a file; set 'weights' to {wanted}")
            if folder.is_dir():
                missing = [name for name in FILES.values() if not (folder / name).is_file()]
                if missing:
                    raise MissingWeightsError(f"{self.who}: config field 'weights' = {value!r}: {folder} holds no {' and no '.join(missing)}; set 'weights' to {wanted}")
                return folder
        where = " or ".join(str(c) for c in candidates)
        raise MissingWeightsError(f"{self.who}: config field 'weights' = {value!r}: no such folder (looked for {where}); set 'weights' to {wanted}")

    def _load(self):  # -> SceneParser
        cfg: CascadeSegConfig = self.config  # type: ignore[assignment]
        device = self.device
        shape = (cfg.network, cfg.classes, str(device))
        if self.random_weights:
            key: tuple[Any, ...] = (RANDOM_WEIGHTS, *shape)
            folder = None
        else:
            folder = self.weights_folder().resolve()
            stamps = tuple((s.st_mtime_ns, s.st_size) for s in ((folder / name).stat() for name in FILES.values()))
            key = (str(folder), stamps, *shape)
        with _LOCK:
            if key not in _NETWORKS:
                _NETWORKS[key] = (self._random() if folder is None else self._from_folder(folder)).to(device).eval()
            return _NETWORKS[key]

    def _random(self):
        from ssga_parser_cascade_seg.model import NETWORKS, SceneParser, init_weights

        cfg: CascadeSegConfig = self.config  # type: ignore[assignment]
        return init_weights(SceneParser(NETWORKS[cfg.network], len(self.class_names)), RANDOM_SEED)

    def _from_folder(self, folder: Path):
        from ssga_parser_cascade_seg.model import NETWORKS, SceneParser, plain_batch_norm_state

        cfg: CascadeSegConfig = self.config  # type: ignore[assignment]
        net = SceneParser(NETWORKS[cfg.network], len(self.class_names))
        for part, module in (("encoder", net.encoder), ("decoder", net.decoder)):
            path = folder / FILES[part]
            expected = (
                f"the {part} of the {cfg.network!r} network with {len(self.class_names)} classes ({cfg.classes}): "
                f"{len(module.state_dict())} keys (the synchronized batch norms' buffers and num_batches_tracked optional), "
                "a raw state dict or under 'state_dict'"
            )
            checkpoint = load_checkpoint(path, self.who, expected)
            state = checkpoint
            if isinstance(checkpoint, dict) and isinstance(checkpoint.get("state_dict"), dict):
                for field in ("network", "classes"):  # ours say what they hold; a release's raw dict does not
                    stored = checkpoint.get(field)
                    if stored is not None and stored != getattr(cfg, field):
                        raise CheckpointError(f"{self.who}: config field 'weights': {path} holds {field} = {stored!r}; set {field} = {stored!r}")
                state = checkpoint["state_dict"]
            if isinstance(state, dict):
                state = plain_batch_norm_state(state, module)
            load_strict(module, state, self.who, path, expected)
        return net

    # ------------------------------------------------------------------ parsing

    def probabilities(self, rgb: np.ndarray) -> np.ndarray:
        """``(C, H, W)`` float32 class probabilities of an ``(H, W, 3)`` uint8 image, averaged over ``image_sizes``."""
        return self.probabilities_many([rgb])[0]

    def probabilities_many(self, images: Sequence[np.ndarray]) -> list[np.ndarray]:
        """:meth:`probabilities` of each of ``images``, the network run once per scale for all images scaled to one size.

        Per image the arithmetic is :func:`.model.predict`'s (CSAIL's ``test.py``): at each
        scale the logits are upsampled to the image's size and soft-maxed, and the scales'
        probabilities are summed in order and averaged. Only images whose input at a scale
        has the same size share a call: padding to a common size would change the logits.
        """
        import torch
        import torch.nn.functional as F

        from ssga_parser_cascade_seg.model import scale_sizes, to_input

        cfg: CascadeSegConfig = self.config  # type: ignore[assignment]
        for rgb in images:  # every image checked before any network work
            if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
                raise InputError(f"{self.who}: expected an (H, W, 3) uint8 RGB image, got shape {rgb.shape} of {rgb.dtype}")
        device = self.device
        sizes = [scale_sizes(rgb.shape[:2], cfg.image_sizes, cfg.max_size, cfg.padding) for rgb in images]
        sums: dict[int, torch.Tensor] = {}
        with torch.inference_mode():
            for scale in range(len(cfg.image_sizes)):
                for members in network_calls([s[scale] for s in sizes], device):
                    x = torch.cat([to_input(images[i], sizes[i][scale], device) for i in members])
                    logits = self.net(x)
                    for row, i in enumerate(members):
                        h, w = images[i].shape[:2]
                        upsampled = F.interpolate(logits[row : row + 1], (h, w), mode="bilinear", align_corners=False)
                        probs = upsampled.softmax(dim=1)[0]
                        sums[i] = sums[i] + probs if i in sums else probs  # scale by scale, as predict adds them
        return [(sums[i] / len(cfg.image_sizes)).float().cpu().numpy() for i in range(len(images))]

    def classify(self, rgb: np.ndarray) -> np.ndarray:
        """``(H, W)`` int32 class index of every pixel (the most probable)."""
        return self.probabilities(rgb).argmax(0).astype(np.int32)

    def _parse(self, view: View) -> Regions:
        return self._parse_many([view])[0]

    def _parse_many(self, views: Sequence[View]) -> list[Regions]:
        probabilities = self.probabilities_many([view.rgb for view in views])
        return [self._regions(view, probs) for view, probs in zip(views, probabilities, strict=True)]

    def _regions(self, view: View, probs: np.ndarray) -> Regions:
        """The regions of ``view`` from its class probabilities ``(C, H, W)``."""
        cfg: CascadeSegConfig = self.config  # type: ignore[assignment]
        classes = probs.argmax(0).astype(np.int32)
        confidence = probs.max(0)
        if cfg.drop_holes and view.synthetic and view.depth is not None:
            classes[~view.valid_depth()] = -1
        if self._ignored.size:
            classes[np.isin(classes, self._ignored)] = -1
        return class_regions(classes, self.class_names, cfg.min_region_px, cfg.connectivity, confidence)



def class_regions(classes: np.ndarray, names: tuple[str, ...], min_px: int, connectivity: int = 8, confidence: np.ndarray | None = None) -> Regions:
    """One region per connected piece of each class of a class map (``-1``: no class) with at least ``min_px`` pixels.

    Regions are numbered by class index, then in the order OpenCV labels a class's
    pieces (deterministic); smaller pieces get no region. ``categories`` holds each
    region's class index, ``names`` its class name and, with ``confidence`` (the
    predicted class's probability per pixel), ``scores`` its mean over the region.
    """
    import cv2

    labels = np.full(classes.shape, -1, dtype=np.int32)
    categories: list[int] = []
    for c in np.unique(classes[classes >= 0]):
        count, pieces, stats, _ = cv2.connectedComponentsWithStats((classes == c).astype(np.uint8), connectivity=connectivity)
        keep = np.flatnonzero(stats[1:, cv2.CC_STAT_AREA] >= min_px) + 1  # piece 0 is everything else
        lut = np.full(count, -1, dtype=np.int32)
        lut[keep] = np.arange(len(categories), len(categories) + len(keep), dtype=np.int32)
        inside = pieces > 0
        labels[inside] = lut[pieces[inside]]
        categories.extend([int(c)] * len(keep))
    k = len(categories)
    scores = None
    if confidence is not None:
        known = labels >= 0
        sums = np.bincount(labels[known], weights=confidence[known], minlength=k)
        scores = (sums / np.maximum(np.bincount(labels[known], minlength=k), 1)).astype(np.float32)
    return Regions(
        labels=labels,
        boxes=boxes_from_labels(labels, k),
        categories=np.asarray(categories, dtype=np.int32),
        names=tuple(names[c] for c in categories),
        scores=scores,
    )


@hookimpl
def ssga_register_parsers() -> list[type[Parser]]:
    return [CascadeSeg]
