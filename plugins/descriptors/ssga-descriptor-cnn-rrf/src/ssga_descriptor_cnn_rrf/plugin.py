"""CNN-RRF, the paper's CNN descriptor (§3.1.2): a VGG place classifier whose class ranking becomes the node feature.

"After training an image classifier with the Vgg16 CNN model, we translate the output
classification results into class-specific reciprocal rank features (RRF) and use RRF
features as graph node features." Here:

* :meth:`CnnRrf.fit` trains the classifier on the training views it is given (each
  cell's real view and, in variants with S, the synthetic views) to tell their place
  classes apart: from scratch (``weights = "scratch"``), or fine-tuned from an ImageNet
  VGG16 file. A trained classifier is cached under a hash of the images, the labels
  and the config, so the variants that fit on the same views train once.
* :meth:`CnnRrf.describe` classifies the whole image and each region's box crop (with a
  margin), all in one batch, and turns each node's class scores into its reciprocal
  ranks: class ``c``'s entry is ``1 / rank of c``, so every node feature is a
  permutation of ``1, 1/2, ..., 1/C`` and ``dim`` is the number of place classes.
* :meth:`CnnRrf.classify` gives the classifier's own class probabilities of a whole
  view (the paper's ``CNN`` row, without graphs).

The network is :class:`~ssga_descriptor_cnn_rrf.vgg.VGG`, plain torch with torchvision's
parameter names. The default is a light network that trains in a few minutes on a
laptop CPU; the ``vgg16`` preset is the paper's VGG16, for GPU machines.
"""

from __future__ import annotations

import functools
import json
import os
import warnings
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from pydantic import Field

from ssga_bench import (
    RANDOM_WEIGHTS, Layout, Learned, LearnedConfig, NotFittedError, atomic_write_bytes, checkpoint_bytes, load_checkpoint,
    load_strict, meta_shapes, read_layout, tensor_state, torch_threads,
)
from ssga_core import CheckpointError, Descriptor, InputError, RegionDescriptor, Regions, View, hookimpl, reciprocal_ranks
from ssga_descriptor_cnn_rrf.layout import LAYOUTS as CONVOLUTIONS
from ssga_descriptor_cnn_rrf.layout import Arch

if TYPE_CHECKING:  # torch, the network and its training load when a classifier is built, not when the plugin registers
    import torch

    from ssga_descriptor_cnn_rrf.training import Augmentation, TrainingResult
    from ssga_descriptor_cnn_rrf.vgg import VGG

HERE = Path(__file__).parent
SCRATCH = "scratch"
"""The ``weights`` value for a classifier trained from random initialisation at ``fit``, on the training views."""
IMAGENET_CLASSES = 1000

LAYOUTS = (
    Layout("vgg16", "torchvision's ImageNet VGG16, vgg16-397923af.pth (the vgg16 preset); place classifiers fine-tuned from it"),
    Layout("vgg16_bn", "torchvision's vgg16_bn-6c64b313.pth; the light classifiers trained here (width 0.125, hidden 256, pool 2)"),
    Layout("vgg11", "torchvision's vgg11-8a719046.pth"),
    Layout("vgg11_bn", "torchvision's vgg11_bn-6002323d.pth"),
)
"""The networks a ``weights`` file can hold. Which one, and its width, hidden and pool sizes,
the file's keys and shapes say; its last layer may have ImageNet's 1000 classes or the places'."""

_RUNTIME_FIELDS = frozenset({"device", "cache", "cache_dir", "describe_batch", "threads"})
"""Config fields that do not change what is trained (left out of the cache key)."""


def _file_shapes(path: Path, who: str) -> dict[str, Any]:
    """The keys and shapes of the weights file at ``path``, as meta tensors (memory-mapped: a
    528 MB VGG16 file is not read to tell its layout), kept per file for the process."""
    stat = path.stat()
    return _shapes_cached(str(path), stat.st_mtime_ns, stat.st_size, who)


@functools.lru_cache(maxsize=8)
def _shapes_cached(path: str, mtime: int, size: int, who: str) -> dict[str, Any]:
    import torch

    expected = "a VGG state dict (" + ", ".join(layout.name for layout in LAYOUTS) + ")"
    try:
        with warnings.catch_warnings():  # the reading below says what is wrong with the file, once
            warnings.simplefilter("ignore")
            checkpoint = torch.load(path, map_location="cpu", weights_only=True, mmap=True)
    except Exception:  # not memory-mappable (an old torch format) or not readable: load_checkpoint says which
        checkpoint = load_checkpoint(Path(path), who, expected)
    state = tensor_state(checkpoint.get("state_dict", checkpoint) if isinstance(checkpoint, dict) else checkpoint, who, path, expected)
    return {k: torch.empty(v.shape, device="meta") for k, v in state.items()}


def _network_of(layout: Layout, state: Mapping[str, Any]) -> tuple[dict[str, Any], dict[str, tuple[int, ...]]]:
    """The network fields of ``layout`` with the sizes the file's first convolution and hidden layers say."""
    from ssga_descriptor_cnn_rrf.vgg import VGG

    arch, batch_norm = layout.name.removesuffix("_bn"), layout.name.endswith("_bn")
    first, hidden, head = (state.get(k) for k in ("features.0.weight", "classifier.0.weight", "classifier.6.weight"))
    width = first.shape[0] / CONVOLUTIONS[arch][0] if first is not None and first.ndim == 4 else 1.0
    last = max(1, round(512 * width))  # the last convolution's channels
    cells = hidden.shape[1] / last if hidden is not None and hidden.ndim == 2 else 49
    pool = max(1, round(cells**0.5))
    rows = int(hidden.shape[0]) if hidden is not None and hidden.ndim == 2 else 4096
    fields = {"arch": arch, "batch_norm": batch_norm, "width": width, "hidden": rows, "pool": pool}
    classes = int(head.shape[0]) if head is not None and head.ndim == 2 else IMAGENET_CLASSES
    return fields, meta_shapes(lambda: VGG(arch, classes, width=width, hidden=rows, pool=pool, batch_norm=batch_norm))


def default_cache_dir() -> Path:
    """``$XDG_CACHE_HOME/ssga/cnn-rrf``, or ``~/.cache/ssga/cnn-rrf``."""
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "ssga" / "cnn-rrf"


class CnnRrfConfig(LearnedConfig):
    """The classifier, its training, and how regions are cropped. The defaults are the ``light`` preset."""

    weights: str = Field(
        default=SCRATCH,
        min_length=1,
        description="'scratch': trained at fit from random initialisation on the training views; a checkpoint file "
        "(relative: the plugin's weights/ folder, torch's hub cache, then the working directory) whose last layer "
        "has 1000 classes (ImageNet: fine-tuned at fit with a new last layer) or the place count (used as is); "
        "'random': untrained (tests only).",
    )
    arch: Arch = Field(default="vgg16", description="Convolution layout: 'vgg16' (13 convolutions) or 'vgg11' (8).")
    width: float = Field(
        default=0.125, gt=0.0, le=1.0, description="Channel multiplier of every convolution (1: VGG's 64...512)."
    )
    batch_norm: bool = Field(default=True, description="A BatchNorm2d after each convolution (torchvision's vgg*_bn names).")
    hidden: int = Field(default=256, ge=1, le=16384, description="Width of the two hidden fully connected layers (VGG: 4096).")
    pool: int = Field(default=2, ge=1, le=16, description="Side of the adaptive average pool before the classifier (VGG: 7).")
    dropout: float = Field(default=0.0, ge=0.0, lt=1.0, description="Dropout of the hidden fully connected layers (VGG: 0.5).")
    input_size: int = Field(default=112, ge=32, le=1024, description="Side (px) every image and region crop is resized to.")
    region_margin: float = Field(
        default=0.1, ge=0.0, le=2.0, description="A region's crop is its box grown by this fraction of its side on every side."
    )
    min_crop: float = Field(default=32.0, ge=1.0, le=4096.0, description="Smallest crop side (px of the view) for a region.")
    steps: int = Field(default=300, ge=0, le=1_000_000, description="Training steps (batches) at fit.")
    batch_size: int = Field(default=32, ge=1, le=4096, description="Augmented samples per training step.")
    lr: float = Field(default=2e-3, gt=0.0, le=1.0, description="Peak AdamW learning rate (5 % warm-up, cosine decay to 0).")
    weight_decay: float = Field(default=5e-4, ge=0.0, le=1.0, description="AdamW weight decay.")
    label_smoothing: float = Field(default=0.1, ge=0.0, lt=1.0, description="Label smoothing of the training loss.")
    region_crops: float = Field(
        default=0.5,
        ge=0.0,
        le=1.0,
        description="Fraction of training samples cropped like regions (1-25 % of the image) rather than whole-image-like.",
    )
    rotation: float = Field(default=10.0, ge=0.0, le=180.0, description="Largest rotation (degrees) of a training sample.")
    colour: float = Field(
        default=0.3, ge=0.0, lt=1.0, description="Brightness, contrast and saturation of a training sample scale by 1 +- this."
    )
    seed: int = Field(default=0, ge=0, description="Seed of initialisation, augmentation and batch order.")
    cache: bool = Field(default=True, description="Keep trained classifiers in cache_dir and load one instead of training again.")
    cache_dir: Path | None = Field(
        default=None, description="Where trained classifiers are kept (default: $XDG_CACHE_HOME/ssga/cnn-rrf)."
    )
    describe_batch: int = Field(default=64, ge=1, le=4096, description="Most crops per forward pass when describing.")
    threads: int = Field(
        default=0,
        ge=0,
        le=1024,
        description="Torch threads on the CPU while fitting and describing (0: torch's setting, every core).",
    )


LIGHT: dict[str, Any] = {
    "weights": SCRATCH, "arch": "vgg16", "width": 0.125, "batch_norm": True, "hidden": 256, "pool": 2, "dropout": 0.0,
    "input_size": 112, "steps": 300, "batch_size": 32, "lr": 2e-3,
}  # fmt: skip
VGG16: dict[str, Any] = {
    "weights": "vgg16-397923af.pth", "arch": "vgg16", "width": 1.0, "batch_norm": False, "hidden": 4096, "pool": 7, "dropout": 0.5,
    "input_size": 224, "steps": 600, "batch_size": 32, "lr": 1e-4,
}  # fmt: skip


class CnnRrf(Learned, RegionDescriptor):
    """A VGG place classifier trained at :meth:`fit`; node features are reciprocal ranks of its class scores."""

    name = "cnn-rrf"
    abbrev = "CNN"
    Config = CnnRrfConfig
    presets = {"light": LIGHT, "vgg16": VGG16}
    layouts = LAYOUTS
    packaged_weights = HERE / "weights"  # where a relative weights file is looked up first (no weights ship: it trains per experiment)
    config: CnnRrfConfig

    def __init__(self, config: CnnRrfConfig | None = None) -> None:
        super().__init__(config)
        # The network the weights file holds, before anything is built from the config: every
        # process that makes this descriptor (a worker loading a fitted state) builds the same.
        if self.config.weights not in (SCRATCH, RANDOM_WEIGHTS):
            path = self._weights_path()
            _, fields = read_layout(self.config, _file_shapes(path, self.who), LAYOUTS, _network_of, self.who, path)
            self.config = self.config.model_copy(update=fields)
        self._net: VGG | None = None
        self._classes: np.ndarray | None = None
        self.training: TrainingResult | None = None
        """What the last :meth:`fit` trained (``None`` if it loaded a cached or finished classifier, or trained nothing)."""
        self.cache_file: Path | None = None
        """The cache file the classifier was written to or loaded from (``None``: not cached)."""

    @property
    def classes(self) -> np.ndarray:
        """The place classes of the classifier's outputs, in output order (ascending): column ``i`` of every feature is class ``classes[i]``."""
        if self._classes is None:
            raise NotFittedError(f"{self.who} is not fitted: its classes are those of the labels given to fit(views, labels)")
        return self._classes

    @property
    def dim(self) -> int:
        if self._classes is None:
            raise NotFittedError(f"{self.who} is not fitted: dim is the number of place classes, known after fit(views, labels)")
        return len(self._classes)

    # -- fit ------------------------------------------------------------------------------

    def fit(self, views: Sequence[View], labels: Sequence[int] | None = None) -> None:
        """Train (or load) the classifier of ``labels``' place classes on ``views``.

        Without labels each view is its own class. With one class there is nothing to
        learn: every node's feature is ``[1.0]``.
        """
        views = list(views)
        if not views:
            raise InputError(f"{self.who}: fit needs at least one training view")
        labels = list(range(len(views))) if labels is None else [int(c) for c in labels]
        if len(labels) != len(views):
            raise InputError(f"{self.who}: fit got {len(views)} views but {len(labels)} labels")
        for view in views:
            self._require(view)
        import torch

        from ssga_descriptor_cnn_rrf.training import stderr_log, train, training_key

        cfg = self.config
        classes = np.unique(np.asarray(labels, dtype=np.int64))
        targets = np.searchsorted(classes, labels)
        device = self.device
        log = stderr_log(self.who)
        # A failed fit leaves the descriptor unfitted, not holding the previous classifier.
        self._net = self._classes = self.training = self.cache_file = None
        with torch_threads(cfg.threads), torch.random.fork_rng(devices=[device] if device.type == "cuda" else []):
            torch.manual_seed(cfg.seed)
            net, learn, start = self._start(classes)
            # channels-last: about 1.5-2x faster convolutions on the CPU (oneDNN), and what cuDNN prefers.
            net.to(device=device, memory_format=torch.channels_last)
            images = [torch.from_numpy(np.ascontiguousarray(v.rgb)).permute(2, 0, 1).contiguous().to(device) for v in views]
            learn = learn and len(classes) > 1 and cfg.steps > 0
            path = None
            if learn and cfg.cache:
                key = training_key([v.rgb for v in views], labels, self._training_json(), start)
                path = (cfg.cache_dir or default_cache_dir()) / f"{key}.pt"
                if self._load_cached(net, path, classes, log):
                    learn = False
                    self.cache_file = path
            if learn:
                what = "training" if cfg.weights == SCRATCH else f"fine-tuning {cfg.weights}:"
                log(f"{what} a {self._layout_name()} classifier ({_parameters(net) / 1e6:.2f} M parameters) of {len(classes)} "
                    f"classes on {len(views)} views, {cfg.steps} steps of {cfg.batch_size} at {cfg.input_size} px on {device}")  # fmt: skip
                self.training = train(
                    net, images, targets, self._augmentation(),
                    steps=cfg.steps, batch_size=cfg.batch_size, lr=cfg.lr, weight_decay=cfg.weight_decay,
                    label_smoothing=cfg.label_smoothing, seed=cfg.seed, log=log,
                )  # fmt: skip
                log(f"trained in {self.training.seconds:.0f} s; accuracy on the training views {self.training.accuracy:.2f}")
                if path is not None:
                    self._save(net, path, classes)
                    self.cache_file = path
        net.eval()
        self._net, self._classes = net, classes

    def state_dict(self) -> dict[str, np.ndarray]:
        """The fitted classifier: its place ``classes`` and its network's tensors (``net.<key>``)."""
        net = self._fitted()
        return {"classes": self.classes.copy(), **{f"net.{k}": v.detach().cpu().numpy() for k, v in net.state_dict().items()}}

    def load_state_dict(self, state: Mapping[str, np.ndarray]) -> None:
        """The classifier :meth:`state_dict` gave, for this config's network."""
        import torch

        if "classes" not in state:
            raise InputError(f"{self.who}: fitted state without 'classes'")
        classes = np.asarray(state["classes"], dtype=np.int64)
        net = self._network(len(classes))
        weights = {k.removeprefix("net."): torch.from_numpy(np.asarray(v)) for k, v in state.items() if k.startswith("net.")}
        try:
            net.load_state_dict(weights, strict=True)
        except RuntimeError as exc:
            raise InputError(f"{self.who}: the fitted state is not a {self._layout_name()} of {len(classes)} classes: {' '.join(str(exc).split())[:200]}") from None
        net.to(device=self.device, memory_format=torch.channels_last)
        net.eval()
        self._net, self._classes, self.training, self.cache_file = net, classes, None, None

    def accuracy(self, views: Sequence[View], labels: Sequence[int]) -> float:
        """Top-1 accuracy of the fitted classifier on whole ``views`` (labels outside :attr:`classes` count as wrong)."""
        import torch

        from ssga_descriptor_cnn_rrf.training import evaluate

        net = self._fitted()
        index = {int(c): i for i, c in enumerate(self.classes)}
        targets = np.array([index.get(int(c), -1) for c in labels])
        images = [torch.from_numpy(np.ascontiguousarray(v.rgb)).permute(2, 0, 1).contiguous().to(self.device) for v in views]
        with torch_threads(self.config.threads):
            return evaluate(net, images, targets, self.config.input_size)

    def _start(self, classes: np.ndarray) -> tuple[VGG, bool, str]:
        """The network to start from, whether ``fit`` trains it, and a digest of where it came from."""
        import torch

        from ssga_descriptor_cnn_rrf.training import file_digest

        cfg = self.config
        n = len(classes)
        if cfg.weights in (SCRATCH, "random"):
            return self._network(n), cfg.weights == SCRATCH, cfg.weights
        path = self._weights_path()
        checkpoint = load_checkpoint(path, self.who, expected=f"a {cfg.arch} state dict")
        state = checkpoint.get("state_dict", checkpoint) if isinstance(checkpoint, dict) else checkpoint
        head = state.get("classifier.6.weight") if isinstance(state, dict) else None
        if isinstance(head, torch.Tensor) and head.ndim == 2 and head.shape[0] == n:
            net = self._network(n)
            load_strict(net, state, self.who, path, expected=f"the {self._layout_name()} layout with {n} place classes")
            stored = checkpoint.get("classes") if isinstance(checkpoint, dict) else None
            if isinstance(stored, torch.Tensor) and stored.numel() == n and not np.array_equal(stored.cpu().numpy(), classes):
                raise CheckpointError(
                    f"{self.who}: config field 'weights': {path} classifies other place classes than fit was given"
                )
            return net, False, file_digest(path)
        net = self._network(IMAGENET_CLASSES)
        expected = f"the {self._layout_name()} layout with a {IMAGENET_CLASSES}-class (ImageNet) or {n}-class (place) last layer"
        load_strict(net, state, self.who, path, expected=expected)
        net.replace_head(n)
        return net, True, file_digest(path)

    def _network(self, n: int) -> VGG:
        from ssga_descriptor_cnn_rrf.vgg import VGG

        cfg = self.config
        return VGG(cfg.arch, n, width=cfg.width, hidden=cfg.hidden, pool=cfg.pool, batch_norm=cfg.batch_norm, dropout=cfg.dropout)

    def _layout_name(self) -> str:
        cfg = self.config
        bn = "_bn" if cfg.batch_norm else ""
        return f"{cfg.arch}{bn} (width {cfg.width:g}, hidden {cfg.hidden}, pool {cfg.pool})"

    def _weights_path(self) -> Path:
        try:
            return self.weights_file()
        except CheckpointError as exc:
            import torch

            hub = Path(torch.hub.get_dir()) / "checkpoints" / self.config.weights
            if not Path(self.config.weights).is_absolute() and hub.is_file():
                return hub
            raise CheckpointError(f"{exc}; not in torch's hub cache ({hub.parent}) either") from None

    def _augmentation(self) -> Augmentation:
        from ssga_descriptor_cnn_rrf.training import Augmentation

        cfg = self.config
        return Augmentation(
            size=cfg.input_size, region_crops=cfg.region_crops, rotation=cfg.rotation, colour=cfg.colour,
            margin=cfg.region_margin, min_side=cfg.min_crop,
        )  # fmt: skip

    def _training_json(self) -> str:
        fields = {k: v for k, v in self.config.model_dump(mode="json").items() if k not in _RUNTIME_FIELDS}
        return json.dumps(fields, sort_keys=True)

    def _load_cached(self, net: VGG, path: Path, classes: np.ndarray, log: Callable[[str], None]) -> bool:
        if not path.is_file():
            return False
        try:
            checkpoint = load_checkpoint(path, self.who, expected="a cached cnn-rrf classifier")
            load_strict(net, checkpoint["state_dict"], self.who, path)
            if not np.array_equal(checkpoint["classes"].numpy(), classes):
                raise CheckpointError(f"{path}: cached for other classes")
        except (CheckpointError, KeyError, TypeError, AttributeError) as exc:
            log(f"warning: ignoring a damaged cache file ({str(exc)[:200]}); training again")
            return False
        log(
            f"loaded the trained classifier from {path} (training accuracy {float(checkpoint.get('accuracy', float('nan'))):.2f})"
        )
        return True

    def _save(self, net: VGG, path: Path, classes: np.ndarray) -> None:
        import torch

        assert self.training is not None
        state = {k: v.detach().cpu() for k, v in net.state_dict().items()}
        record = {
            "state_dict": state,
            "classes": torch.as_tensor(classes, dtype=torch.int64),
            "accuracy": self.training.accuracy,
            "seconds": self.training.seconds,
            "config": self._training_json(),
        }
        atomic_write_bytes(path, checkpoint_bytes(record))

    # -- describe -------------------------------------------------------------------------

    def _fitted(self) -> VGG:
        if self._net is None:
            raise NotFittedError(f"{self.who} is not fitted: call fit(views, labels) first")
        return self._net

    def scores(self, view: View, boxes: Sequence[tuple[int, int, int, int]]) -> np.ndarray:
        """``(len(boxes), C)`` class logits of the crops ``(x0, y0, x1, y1)`` of ``view``, in :attr:`classes` order."""
        import torch

        from ssga_descriptor_cnn_rrf.training import crop_batch
        from ssga_descriptor_cnn_rrf.vgg import normalise

        net = self._fitted()
        cfg = self.config
        image = torch.from_numpy(np.ascontiguousarray(view.rgb)).permute(2, 0, 1).to(self.device)
        out = []
        with torch.no_grad(), torch_threads(cfg.threads):
            for s in range(0, len(boxes), cfg.describe_batch):
                x = normalise(crop_batch(image, boxes[s : s + cfg.describe_batch], cfg.input_size))
                out.append(net(x.contiguous(memory_format=torch.channels_last)).float().cpu())
        return torch.cat(out).numpy()

    def crops(self, view: View, regions: Regions | None) -> list[tuple[int, int, int, int]]:
        """The crops ``(x0, y0, x1, y1)`` that describe ``view``: the whole image, then each region's grown box."""
        from ssga_descriptor_cnn_rrf.training import expand_box

        h, w = view.camera.shape
        boxes = [(0, 0, w, h)]
        if regions is not None:
            cfg = self.config
            boxes += [expand_box(b, (h, w), cfg.region_margin, cfg.min_crop) for b in regions.boxes]
        return boxes

    def _describe(self, view: View, regions: Regions | None) -> np.ndarray:
        return reciprocal_ranks(self.scores(view, self.crops(view, regions))).astype(np.float32)

    def classify(self, view: View) -> np.ndarray:
        """``(C,)``: the classifier's probability of each place class for the whole view, in :attr:`classes` order."""
        self._require(view)
        logits = self.scores(view, self.crops(view, None))[0]
        e = np.exp(logits - logits.max())
        return (e / e.sum()).astype(np.float32)


def _parameters(net: torch.nn.Module) -> int:
    return sum(p.numel() for p in net.parameters())


@hookimpl
def ssga_register_descriptors() -> list[type[Descriptor]]:
    return [CnnRrf]
