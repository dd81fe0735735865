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
``provenance.json`` beside the files). An official release folder
(``ade20k-resnet50dilated-ppm_deepsup``...), which the user places, loads by itself: the
files' keys and shapes say the network (:data:`LAYOUTS`), and the class count of the
decoder's last layer says the vocabulary.
"""

from __future__ import annotations

import difflib
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Annotated, Any, ClassVar, Literal, Self

import numpy as np
from pydantic import Field, model_validator

from ssga_core import CheckpointError, Data, InputError, MissingWeightsError, Parser, Regions, View, boxes_from_labels, hookimpl
from ssga_bench import (
    RANDOM_SEED, Layout, Learned, LearnedConfig, load_checkpoint, load_strict, meta_shapes, network_calls, network_field,
    read_layout, tensor_state, weights_field,
)
from ssga_parser_cascade_seg.classes import VOCABULARIES

WEIGHTS_DIR = Path(__file__).parent / "weights"
"""Where relative ``weights`` folders are looked up first (then the working directory)."""

LIGHT_WEIGHTS = "procedural-light-ppm_deepsup"
"""The packaged light network's folder in :data:`WEIGHTS_DIR`."""

FILES = {"encoder": "encoder_epoch_20.pth", "decoder": "decoder_epoch_20.pth"}
"""A release folder's files (CSAIL's ``demo_test.sh``)."""

LAYOUTS = (
    Layout("light", f"trained here on procedural homes: weights/{LIGHT_WEIGHTS}/, the default"),
    Layout("resnet18dilated", "CSAIL's ADE20K release: the folder ade20k-resnet18dilated-ppm_deepsup at sceneparsing.csail.mit.edu/model/pytorch/"),
    Layout("resnet50dilated", "CSAIL's ADE20K release, the paper's: the folder ade20k-resnet50dilated-ppm_deepsup at sceneparsing.csail.mit.edu/model/pytorch/"),
)
"""The networks a ``weights`` folder can hold; which one, its files' keys and shapes say."""

RANDOM_NETWORK, RANDOM_CLASSES = "light", "procedural"
"""The network and vocabulary random weights build (tests only), where the config leaves them out."""

PART_EXPECTED = (
    "the encoder or decoder of a 'light', 'resnet18dilated' or 'resnet50dilated' network: a raw state dict "
    "(CSAIL's releases) or one under 'state_dict' (ours)"
)

ORIGINAL_SCALES = (300, 375, 450, 525, 600)
"""CSAIL's test scales (shorter side, ``DATASET.imgSizes``) for the official releases."""

LIGHT_SCALES = (176, 216, 256, 296, 336)
"""The same ratios around the light network's 256-pixel views: its multi-scale setting."""



ALL_CLASSES = tuple(dict.fromkeys(name for names in VOCABULARIES.values() for name in names))
"""Every vocabulary's names, once each."""


def unknown_class(wanted: Iterable[str], names: Sequence[str], said: str) -> str:
    """The first of ``wanted`` that is not in ``names`` (the vocabulary ``said``), in words with close names; "" if none."""
    for name in wanted:
        if name not in names:
            close = difflib.get_close_matches(name, names, n=3)
            hint = f"; did you mean {', '.join(map(repr, close))}?" if close else ""
            return f"{name!r} is no class of {said}{hint}"
    return ""


class CascadeSegConfig(LearnedConfig):
    added_since: ClassVar[frozenset[str]] = frozenset({"split_px"})

    weights: str = weights_field(
        LIGHT_WEIGHTS,
        "an official release such as 'ade20k-resnet50dilated-ppm_deepsup'",
        what="Folder holding encoder_epoch_20.pth and decoder_epoch_20.pth, as CSAIL's releases are laid out",
    )
    network: Literal["light", "resnet18dilated", "resnet50dilated"] | None = network_field(
        "Encoder layout (decoder: PPM with deep supervision): 'light' (ResNet18-dilated at a quarter of its widths, the "
        "packaged weights), or the official 'resnet18dilated' (fc_dim 512) or 'resnet50dilated' (fc_dim 2048).",
        files="the weights files'",
    )
    classes: Literal["procedural", "ade20k"] | None = Field(
        default=None,
        description="The vocabulary the weights predict: 'procedural' (13 categories of procedural homes, the "
        "packaged weights) or 'ade20k' (ADE20K's 150, the official releases). Left out: the weights files', read "
        "from the class count of the decoder's last layer ('procedural' for random weights); set, the files must hold it.",
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
    split_px: int = Field(
        default=0,
        ge=0,
        le=1 << 24,
        description="A piece larger than this many pixels is cut into ceil(area / split_px) compact parts of its "
        "class (SLICO superpixels inside the piece), so that a wall or a floor is several parts, as a superpixel "
        "parser's are; 0 keeps every piece whole (the paper's parser). 2600 is SLICO's 'coarse' superpixel at 256 x 256.",
    )
    ignore_classes: tuple[str, ...] = Field(
        default=(),
        max_length=256,
        description="Class names (of the vocabulary in 'classes', or the weights') whose pixels get no region, e.g. wall, floor, ceiling.",
    )
    drop_holes: bool = Field(
        default=True,
        description="In a synthetic view with depth, pixels the synthesizer left empty (no depth) get no region, so "
        "the holes do not become parts of the graph.",
    )

    @model_validator(mode="after")
    def _known_classes(self) -> Self:
        # With classes left out the weights say the vocabulary: a name of none is a typo now,
        # a name of another than the weights' is found when they load (CascadeSeg.__init__).
        said = f"classes = {self.classes!r}" if self.classes else f"any vocabulary ({', '.join(map(repr, VOCABULARIES))})"
        problem = unknown_class(self.ignore_classes, VOCABULARIES[self.classes] if self.classes else ALL_CLASSES, said)
        if problem:
            raise ValueError(f"ignore_classes: {problem}")
        return self




class CascadeSeg(Learned, Parser):
    """One region per connected piece of each predicted class (class index, name and mean probability per region).

    The network loads when the parser is made (a bad ``weights`` folder is reported
    before any work), once per process for every instance that uses the same files.
    """

    name = "cascade-seg"
    abbrev = "SE"  # the paper's tables: "P-SE (PDS)"
    Config = CascadeSegConfig
    names_categories = True  # each region's class index in the vocabulary
    regions_are_category_pieces = True  # one region per connected piece of a class (class_regions)
    reloaded = ("net",)
    layouts = LAYOUTS
    packaged_weights = WEIGHTS_DIR
    trained_on = "procedural"  # the workspace source whose homes the packaged weights saw
    consumes = frozenset({Data.RGB})
    presets = {
        "light": {},
        "light-multiscale": {"image_sizes": LIGHT_SCALES},
        "ade20k-resnet18dilated-ppm_deepsup": {"weights": "ade20k-resnet18dilated-ppm_deepsup", "image_sizes": ORIGINAL_SCALES},
        "ade20k-resnet50dilated-ppm_deepsup": {"weights": "ade20k-resnet50dilated-ppm_deepsup", "image_sizes": ORIGINAL_SCALES},
    }

    def __init__(self, config: CascadeSegConfig | None = None) -> None:
        super().__init__(config)
        cfg: CascadeSegConfig = self.config  # type: ignore[assignment]  # now with the weights' network and classes
        self.regions_cut_from_pieces = cfg.split_px > 0
        self.class_names: tuple[str, ...] = VOCABULARIES[cfg.classes]  # type: ignore[index]
        problem = unknown_class(cfg.ignore_classes, self.class_names, f"classes = {cfg.classes!r}, the vocabulary of config field 'weights' = {cfg.weights!r}")
        if problem:
            raise CheckpointError(f"{self.who}: config field 'ignore_classes': {problem}")
        self._ignored = np.array([self.class_names.index(n) for n in cfg.ignore_classes], dtype=np.int64)

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
        """The network, once per process per folder; ``self.config`` gets the files' ``network`` and ``classes``."""
        cfg: CascadeSegConfig = self.config  # type: ignore[assignment]
        net, _ = self.load_network(
            (cfg.network, cfg.classes), self._random, self._from_folder,
            find=self.weights_folder, files=lambda folder: [folder / name for name in FILES.values()],
        )  # fmt: skip
        return net

    def _random(self):  # -> (SceneParser, fields)
        from ssga_parser_cascade_seg.model import init_weights

        cfg: CascadeSegConfig = self.config  # type: ignore[assignment]
        fields = {"network": cfg.network or RANDOM_NETWORK, "classes": cfg.classes or RANDOM_CLASSES}
        return init_weights(_scene_parser(fields), RANDOM_SEED), fields

    def _from_folder(self, folder: Path):  # -> (SceneParser, fields)
        """Both files as one checkpoint: their union says the layout (a light encoder beside a ResNet50 decoder is none)."""
        states = {f"{part}.{key}": value for part in FILES for key, value in self._part_state(folder / FILES[part]).items()}
        _, fields = read_layout(self.config, _in_files(states), LAYOUTS, self._network_of, self.who, folder)
        net = _scene_parser(fields)
        load_strict(net, states, self.who, folder, f"the {fields['network']!r} network with classes = {fields['classes']!r}")
        return net, fields

    def _part_state(self, path: Path) -> dict[str, Any]:
        """One file's state dict, raw (CSAIL's) or under ``state_dict`` (ours), its batch-norm bookkeeping made plain.

        Ours also say their ``network`` and ``classes``: provenance only, the keys and
        shapes decide, as for a release's raw dict.
        """
        from ssga_parser_cascade_seg.model import plain_batch_norm_state

        checkpoint = load_checkpoint(path, self.who, PART_EXPECTED)
        state = checkpoint["state_dict"] if isinstance(checkpoint, dict) and isinstance(checkpoint.get("state_dict"), dict) else checkpoint
        return plain_batch_norm_state(tensor_state(state, self.who, path, PART_EXPECTED))

    def _network_of(self, layout: Layout, state: Mapping[str, Any]) -> tuple[dict[str, Any], dict[str, tuple[int, ...]]]:
        """The fields, keys and shapes of ``layout``'s network with the vocabulary of the files' class count."""
        fields = {"network": layout.name, "classes": _classes(state, self.config.classes)}
        return fields, _in_files(meta_shapes(lambda: _scene_parser(fields)))

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
        return class_regions(classes, self.class_names, cfg.min_region_px, cfg.connectivity, confidence, view.rgb, cfg.split_px)



def _scene_parser(fields: Mapping[str, Any]):  # -> SceneParser
    from ssga_parser_cascade_seg.model import NETWORKS, SceneParser

    return SceneParser(NETWORKS[fields["network"]], len(VOCABULARIES[fields["classes"]]))


def _in_files(entries: Mapping[str, Any]) -> dict[str, Any]:
    """``SceneParser``'s keys (``encoder.*``, ``decoder.*``) as ``encoder_epoch_20.pth:*``, ``decoder_epoch_20.pth:*``,
    so that a mismatch names the file and the key in it."""
    named = {}
    for key, value in entries.items():
        part, _, rest = key.partition(".")
        named[f"{FILES[part]}:{rest}"] = value
    return named


def _classes(state: Mapping[str, Any], configured: str | None) -> str:
    """The vocabulary of the files' class count, the outputs of the decoder's last layer (the vocabularies' counts differ).

    A count no vocabulary has gives the configured one (else the random weights'), so the
    mismatch is reported as that layer's wrong shape.
    """
    from ssga_parser_cascade_seg.model import CLASSIFIER

    last = state.get(f"{FILES['decoder']}:{CLASSIFIER}")
    count = int(last.shape[0]) if last is not None and last.ndim == 4 else None
    return next((name for name, names in VOCABULARIES.items() if len(names) == count), configured or RANDOM_CLASSES)


def class_regions(
    classes: np.ndarray, names: tuple[str, ...], min_px: int, connectivity: int = 8, confidence: np.ndarray | None = None,
    rgb: np.ndarray | None = None, split_px: int = 0,
) -> Regions:
    """One region per connected piece of each class of a class map (``-1``: no class) with at least ``min_px`` pixels.

    Regions are numbered by class index, then in the order OpenCV labels a class's
    pieces (deterministic); smaller pieces get no region. ``categories`` holds each
    region's class index, ``names`` its class name and, with ``confidence`` (the
    predicted class's probability per pixel), ``scores`` its mean over the region.
    With ``split_px`` (and the image ``rgb``), a piece larger than that is cut into
    parts of its class in its place (:func:`cut_pieces`).
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
    piece_classes = np.asarray(categories, dtype=np.int32)
    if split_px:
        if rgb is None:
            raise InputError("class_regions: split_px needs the image (rgb) to cut the pieces by")
        labels, piece = cut_pieces(labels, len(piece_classes), rgb, split_px)
        piece_classes = piece_classes[piece]
    k = len(piece_classes)
    scores = None
    if confidence is not None:
        known = labels >= 0
        sums = np.bincount(labels[known], weights=confidence[known], minlength=k)
        scores = (sums / np.maximum(np.bincount(labels[known], minlength=k), 1)).astype(np.float32)
    return Regions(
        labels=labels,
        boxes=boxes_from_labels(labels, k),
        categories=piece_classes,
        names=tuple(names[c] for c in piece_classes),
        scores=scores,
    )


def cut_pieces(labels: np.ndarray, count: int, rgb: np.ndarray, max_px: int) -> tuple[np.ndarray, np.ndarray]:
    """A label map of ``count`` regions with each region larger than ``max_px`` pixels cut into about
    ``ceil(area / max_px)`` compact parts: SLICO superpixels of ``rgb`` inside the region, numbered in the
    region's place, in SLIC's order. Returns the new label map and, per new region, the region it is part of.
    """
    from skimage.segmentation import slic  # imported here: keeps plugin discovery light

    cut_labels = np.full(labels.shape, -1, dtype=np.int32)
    source: list[int] = []  # per new region, the region it is a part of
    areas = np.bincount(labels[labels >= 0], minlength=count)
    for r in range(count):
        inside = labels == r
        parts = int(np.ceil(areas[r] / max_px))
        if parts <= 1:
            cut_labels[inside] = len(source)
            source.append(r)
            continue
        rows, cols = np.flatnonzero(inside.any(1)), np.flatnonzero(inside.any(0))
        box = np.s_[rows[0] : rows[-1] + 1, cols[0] : cols[-1] + 1]  # SLIC on the region's box only: cheaper
        mask = inside[box]
        cut = slic(
            rgb[box], n_segments=parts, mask=mask, slic_zero=True, start_label=1, enforce_connectivity=True, channel_axis=-1
        )[mask]  # fmt: skip
        cut[cut == 0] = cut.max(initial=1)  # SLIC labels every pixel of the mask; should one be left, it stays in the region
        present, numbered = np.unique(cut, return_inverse=True)
        cut_labels[box][mask] = len(source) + numbered.astype(np.int32)
        source.extend([r] * len(present))
    return cut_labels, np.asarray(source, dtype=np.int64)


@hookimpl
def ssga_register_parsers() -> list[type[Parser]]:
    return [CascadeSeg]
