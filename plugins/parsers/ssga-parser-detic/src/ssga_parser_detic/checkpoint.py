"""What Detic's released checkpoint holds, and its strict loading.

The file is a detectron2/fvcore checkpoint, ``{'model': state_dict, ...}`` (other
top-level entries, such as ``__author__``, ``matching_heuristics`` or ``iteration``, are
ignored). Its state dict is the network's (:class:`~ssga_parser_detic.model.DeticR50`),
checked key by key and shape by shape, plus:

* ``roi_heads.box_predictor.{0,1,2}.cls_score.zs_weight``: the classifier's class
  embeddings of the training vocabulary, ``(512, C + 1)`` (22048 columns for the
  LVIS+COCO+ImageNet-21k model, C is the file's): required, then replaced by the
  configured vocabulary, as Detic's ``reset_cls_test`` does at test time;
* :data:`OPTIONAL_KEYS`, which inference never reads, accepted with or without.

The keys and shapes are compared with the plugin's layouts by the learned-stage kit's
:func:`~ssga_bench.read_layout`, so a file of another network is said as every learned
plugin says it: the closest layout and its first missing, unexpected or wrongly shaped keys.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import torch

from ssga_bench import Layout, load_strict, meta_shapes, read_layout, tensor_state
from ssga_core import CheckpointError
from ssga_parser_detic.model import CASCADE_BOX_WEIGHTS, EMBED_DIM, DeticR50

ZS_WEIGHT_KEYS = tuple(f"roi_heads.box_predictor.{k}.cls_score.zs_weight" for k in range(len(CASCADE_BOX_WEIGHTS)))

OPTIONAL_KEYS: dict[str, tuple[int | None, ...]] = {
    "backbone.bottom_up.base.fc.weight": (None, 2048),
    "backbone.bottom_up.base.fc.bias": (None,),
    "pixel_mean": (3, 1, 1),
    "pixel_std": (3, 1, 1),
}
"""Keys a file may hold that inference never reads, with their shapes (``None``: any length).

Detic builds timm's ResNet-50 with its ImageNet-21k classifier (``fc``, 11221 classes),
which detection never calls; older detectron2 versions stored the pixel statistics as
buffers. Neither could be checked against a released file here, so both are accepted
when their shapes are right, and dropped.
"""


def layout(net: torch.nn.Module) -> str:
    """The key families and count a file must hold for ``net``, for error messages."""
    return (
        "backbone.bottom_up.base.*, backbone.fpn_*, backbone.top_block.*, proposal_generator.centernet_head.*, roi_heads.*; "
        f"{len(net.state_dict()) + len(ZS_WEIGHT_KEYS)} keys"
    )


def model_state(checkpoint: Any) -> tuple[dict[str, Any] | None, str]:
    """The ``model`` state dict of a checkpoint (or a bare state dict), or ``(None, what it is instead)``."""
    if isinstance(checkpoint, dict) and isinstance(checkpoint.get("model"), dict):
        return checkpoint["model"], ""
    if isinstance(checkpoint, dict) and checkpoint and all(isinstance(v, torch.Tensor) for v in checkpoint.values()):
        return checkpoint, ""
    if isinstance(checkpoint, dict):
        return None, f"a dict of {sorted(map(str, checkpoint))[:5]} and no 'model' state dict"
    return None, f"a {type(checkpoint).__name__}, not a dict"


def network_state(checkpoint: Any, who: str, path: Path | str, expected: str) -> dict[str, torch.Tensor]:
    """The checkpoint's state dict of tensors without the :data:`OPTIONAL_KEYS` of the right shapes; else one :class:`CheckpointError` line.

    An optional key of an unexpected shape stays, so the layout check names it.
    """
    state, what = model_state(checkpoint)
    if state is None:
        raise CheckpointError(f"{who}: config field 'weights': {path} holds {what}; expected {expected}")
    rest = dict(tensor_state(state, who, path, expected))
    for key, shape in OPTIONAL_KEYS.items():
        value = rest.get(key)
        if value is not None and value.ndim == len(shape) and all(s in (None, d) for s, d in zip(shape, value.shape, strict=True)):
            del rest[key]
    # detectron2 since May 2023 (d4a5f28e) gives FrozenBatchNorm2d a num_batches_tracked counter, so a
    # file it saved again holds 53 of them; frozen statistics never count, and the 2022 release has none.
    frozen = {key.removesuffix("running_mean") + "num_batches_tracked" for key in rest if key.endswith(".running_mean")}
    for key in [k for k in rest if k in frozen and rest[k].ndim == 0]:
        del rest[key]
    return rest


def file_shapes(state: Mapping[str, torch.Tensor]) -> dict[str, tuple[int, ...]]:
    """The keys and shapes of a file of :class:`DeticR50`: the network's, and each stage's class embeddings
    ``(512, C + 1)`` with the file's C (any training vocabulary loads: the configured one replaces it)."""
    shapes = meta_shapes(DeticR50)
    for key in ZS_WEIGHT_KEYS:
        value = state.get(key)
        shapes[key] = (EMBED_DIM, int(value.shape[-1]) if value is not None and value.ndim else 1)
    return shapes


def load_state(net: DeticR50, checkpoint: Any, who: str, path: Path | str, expected: str, layouts: Sequence[Layout], config: Any) -> None:
    """Load a checkpoint's network weights into ``net`` strictly; any mismatch is one :class:`CheckpointError` line.

    ``layouts`` (the plugin's) all build :class:`DeticR50`: a file matching one loads into
    ``net``; one matching none names the closest. They set no config field, so ``config``
    is never contradicted.
    """
    state = network_state(checkpoint, who, path, expected)
    read_layout(config, state, layouts, lambda _layout, file: ({}, file_shapes(file)), who, path)
    load_strict(net, {k: v for k, v in state.items() if k not in ZS_WEIGHT_KEYS}, who, path, expected)
