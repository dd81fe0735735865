"""The ``detic`` parser: Detic's detections as scene-graph parts, the paper's P-DE parser (§3.1.1).

Detic (Zhou et al., ECCV 2022) detects and segments objects of any vocabulary given as
CLIP text embeddings; the paper uses its LVIS vocabulary (1203 classes). The network is
:mod:`.model` (its ResNet-50 configuration in plain torch, loading the released
detectron2 checkpoint strictly); :mod:`.vocabulary` reads the class embeddings and names.

Each detection above ``score_threshold`` becomes a region: its mask (pasted into the
image at 0.5, as detectron2 does), its own box, class and score. Where masks overlap, a
pixel belongs to the highest-scoring detection; a detection left with no pixel is
dropped. Nothing of Detic is shipped: without its checkpoint (``weights``) the parser
raises :class:`~ssga_core.MissingWeightsError` naming the field and the file, and an
experiment reports its rows as not run.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
from pydantic import Field

from ssga_bench import RANDOM_SEED, RANDOM_WEIGHTS, Layout, Learned, LearnedConfig, file_stamp, find_weights, load_checkpoint

if TYPE_CHECKING:  # torch loads when the parser is made, not when the plugin registers
    from ssga_parser_detic.model import Settings
from ssga_core import CheckpointError, MissingWeightsError, Parser, Regions, View, hookimpl

R50_CHECKPOINT = "Detic_LCOCOI21k_CLIP_R5021k_640b32_4x_ft4x_max-size.pth"
"""The released model of Detic's ResNet-50 config of the same name (LVIS + COCO boxes, ImageNet-21k image labels)."""
R50_URL = f"https://dl.fbaipublicfiles.com/detic/{R50_CHECKPOINT}"

LAYOUTS = (
    Layout(
        "resnet50-in21k",
        f"Detic's released ResNet-50 (ImageNet-21k backbone, CenterNet2, CLIP classifier): {R50_URL}",
    ),
)
"""The networks a ``weights`` file can hold: one, the network built here (Detic's Swin-B, ConvNeXt-T and
ResNet-18 models have other backbones). The file's keys and shapes are checked against it; it sets no config field."""

LVIS_EMBEDDINGS = "lvis_v1_clip_a+cname.npy"
LVIS_NAMES = "lvis_v1_train_cat_info.json"



class DeticConfig(LearnedConfig):
    weights: str = Field(
        default=R50_CHECKPOINT,
        min_length=1,
        description=f"Detic's released ResNet-50 checkpoint (relative: the working directory), from {R50_URL}; "
        "or 'random' (tests only).",
    )
    vocabulary: str = Field(
        default=LVIS_EMBEDDINGS,
        min_length=1,
        description="Class embeddings, a (classes, 512) .npy of CLIP text features (Detic's datasets/metadata/"
        f"{LVIS_EMBEDDINGS}: LVIS, 1203 classes). Relative: beside the checkpoint, then the working directory.",
    )
    class_names: str = Field(
        default=LVIS_NAMES,
        min_length=1,
        description=f"The classes' names in the embeddings' order: Detic's datasets/metadata/{LVIS_NAMES} (LVIS "
        "categories by id), a JSON list or a text file of one name per line. Relative: as vocabulary.",
    )
    score_threshold: float = Field(
        default=0.5, ge=0.0, lt=1.0, description="Detections scoring above this become regions (Detic's demo: 0.5; its evaluation: 0.02)."
    )
    nms_threshold: float = Field(default=0.5, gt=0.0, le=1.0, description="IoU above which a lower-scoring box of the same class is dropped.")
    max_detections: int = Field(default=300, ge=1, le=10000, description="At most this many detections per image, the best.")
    one_class_per_proposal: bool = Field(
        default=True, description="Each box keeps only its best class (the demo); false: one detection per class above the threshold."
    )
    resize: Literal["max-size", "shortest-edge"] = Field(
        default="max-size",
        description="'max-size': the longer side becomes test_size (Detic's EfficientDetResizeCrop at test time); "
        "'shortest-edge': the shorter side becomes test_size, the longer at most max_size (detectron2's DefaultPredictor, "
        "Detic's demo).",
    )
    test_size: int = Field(default=640, ge=32, le=4096, description="Target side in pixels of the resize (see resize).")
    max_size: int = Field(default=1333, ge=32, le=8192, description="Longest side after a 'shortest-edge' resize.")
    drop_holes: bool = Field(
        default=True,
        description="In a synthetic view with depth, pixels the synthesizer left empty get no region; "
        "a detection left with no pixel is dropped.",
    )


class DeticParser(Learned, Parser):
    """Detic's instance masks, one region per detection, with class names and scores.

    The network and the vocabulary load when the parser is made (a missing or bad file is
    reported before any work), once per process for every instance using the same files.
    """

    name = "detic"
    abbrev = "DE"  # the paper's tables: "P-DE (PDS)"
    Config = DeticConfig
    names_categories = True  # each detection's class in the vocabulary
    reloaded = ("net", "names")
    layouts = LAYOUTS
    presets = {
        "demo": {"resize": "shortest-edge", "test_size": 800, "max_size": 1333},
        "all-classes": {"one_class_per_proposal": False},
    }

    @property
    def settings(self) -> Settings:
        from ssga_parser_detic.model import Settings

        cfg: DeticConfig = self.config  # type: ignore[assignment]
        return Settings(
            score_threshold=cfg.score_threshold,
            nms_threshold=cfg.nms_threshold,
            max_detections=cfg.max_detections,
            one_class_per_proposal=cfg.one_class_per_proposal,
            resize=cfg.resize,
            size=cfg.test_size,
            max_size=cfg.max_size,
        )

    # ------------------------------------------------------------------ loading

    def _load(self) -> tuple[Any, tuple[str, ...]]:
        import torch

        from ssga_parser_detic.vocabulary import EMBEDDINGS_EXPECTED, NAMES_EXPECTED, read_embeddings, read_names

        cfg: DeticConfig = self.config  # type: ignore[assignment]
        checkpoint = None if self.random_weights else self._checkpoint_file()
        near = checkpoint.parent if checkpoint is not None else None
        vocabulary = find_weights(cfg.vocabulary, near, self.who, "vocabulary", EMBEDDINGS_EXPECTED)
        names_file = find_weights(cfg.class_names, near, self.who, "class_names", NAMES_EXPECTED)
        names = read_names(names_file, self.who)
        files = [f for f in (checkpoint, vocabulary) if f is not None]

        def load():  # -> DeticR50
            embeddings = read_embeddings(vocabulary, self.who)
            net = self._random() if checkpoint is None else self._from_file(checkpoint)
            net.set_vocabulary(torch.from_numpy(embeddings))
            return net.to(self.device).eval()

        key = (RANDOM_WEIGHTS if checkpoint is None else "", *(file_stamp(f.resolve()) for f in files), str(self.device))
        net = self.once_per_process(key, load)
        if net.num_classes != len(names):
            raise CheckpointError(
                f"{self.who}: config field 'class_names': {names_file} names {len(names)} classes, but the vocabulary "
                f"{vocabulary} embeds {net.num_classes}; expected one name per embedding row, in order"
            )
        return net, names

    def _checkpoint_file(self) -> Path:
        try:
            return self.weights_file()
        except MissingWeightsError as exc:
            raise MissingWeightsError(f"{exc}; Detic's ResNet-50 model is {R50_URL}") from None

    def _random(self):
        from ssga_parser_detic.model import DeticR50, init_random

        return init_random(DeticR50(), RANDOM_SEED)

    def _from_file(self, path: Path):
        from ssga_parser_detic.checkpoint import layout, load_state
        from ssga_parser_detic.model import DeticR50

        net = DeticR50()
        expected = f"a detectron2 checkpoint {{'model': state dict}} of Detic's ResNet-50 configuration, as {R50_CHECKPOINT} ({layout(net)})"
        load_state(net, load_checkpoint(path, self.who, expected), self.who, path, expected, LAYOUTS, self.config)
        return net

    # ------------------------------------------------------------------ parsing

    def _parse(self, view: View) -> Regions:
        from ssga_parser_detic.model import detect

        cfg: DeticConfig = self.config  # type: ignore[assignment]
        found = detect(self.net, view.rgb, self.settings)
        masks = found.masks
        if cfg.drop_holes and view.synthetic and view.depth is not None:
            masks = masks & view.valid_depth()[None]
        labels = owners(masks)
        regions = Regions(
            labels=labels,
            boxes=pixel_centre_boxes(found.boxes, view.camera.shape),
            categories=found.classes.astype(np.int32),
            names=tuple(self.names[c] for c in found.classes),
            scores=found.scores.astype(np.float32),
        )
        return regions.select(np.bincount(labels[labels >= 0], minlength=len(found)) > 0)  # detections with pixels

    # No _parse_many: the default parses one view at a time, on purpose. Most of a parse is per image,
    # on shapes that depend on the image (CenterNet's proposals by top-k and NMS, the three cascade
    # stages on that image's own proposals, per-class NMS, masks pasted at its size); only the backbone
    # and CenterNet's conv tower could share a call. On the CPU that gains nothing: with one torch
    # thread, test_size 256 and random weights the backbone is 15 % of a parse, and four views through
    # it in one call took as long as four calls (0.51 s against 4 x 0.13 s). On a GPU a batched backbone
    # would pay, but it needs DeticR50.forward and detect (model.py) split into a batched feature step
    # and a per-image head step; written here, it would copy their bodies.


def owners(masks: np.ndarray) -> np.ndarray:
    """``(H, W)`` int32: the first (highest-scoring) of ``(N, H, W)`` masks covering each pixel, ``-1`` where none does."""
    if not len(masks):
        return np.full(masks.shape[1:], -1, dtype=np.int32)
    return np.where(masks.any(axis=0), masks.argmax(axis=0), -1).astype(np.int32)


def pixel_centre_boxes(boxes: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Detector boxes (pixel ``i`` spans ``[i, i + 1)``) in ssga's pixel-centre coordinates, inside the image."""
    h, w = shape
    out = np.asarray(boxes, dtype=np.float32).reshape(-1, 4) - 0.5
    out[:, 0::2] = out[:, 0::2].clip(0, w - 1)
    out[:, 1::2] = out[:, 1::2].clip(0, h - 1)
    return out


@hookimpl
def ssga_register_parsers() -> list[type[Parser]]:
    return [DeticParser]
