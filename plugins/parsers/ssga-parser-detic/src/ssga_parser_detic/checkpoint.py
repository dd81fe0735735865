"""What Detic's released checkpoint holds, and its strict loading.

The file is a detectron2/fvcore checkpoint, ``{'model': state_dict, ...}`` (other
top-level entries, such as ``__author__``, ``matching_heuristics`` or ``iteration``, are
ignored). Its state dict is the network's (:class:`~ssga_parser_detic.model.DeticR50`),
checked key by key and shape by shape, plus:

* ``roi_heads.box_predictor.{0,1,2}.cls_score.zs_weight``: the classifier's class
  embeddings of the training vocabulary, ``(512, C + 1)`` (22048 columns for the
  LVIS+COCO+ImageNet-21k model): required, then replaced by the configured vocabulary,
  as Detic's ``reset_cls_test`` does at test time;
* :data:`OPTIONAL_KEYS`, which inference never reads, accepted with or without.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch

from ssga_bench import load_strict
from ssga_core import CheckpointError
from ssga_parser_detic.model import CASCADE_BOX_WEIGHTS, EMBED_DIM

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


def split_state(state: dict[str, Any]) -> tuple[dict[str, Any], list[str]]:
    """``state`` without its class embeddings and the optional keys, and what is wrong with the embeddings.

    An optional key of an unexpected shape stays, so the strict load names it.
    """
    rest = dict(state)
    problems = []
    for key in ZS_WEIGHT_KEYS:
        value = rest.pop(key, None)
        if not isinstance(value, torch.Tensor):
            problems.append(f"missing {key}")
        elif value.ndim != 2 or value.shape[0] != EMBED_DIM:
            problems.append(f"{key} {tuple(value.shape)} (expected ({EMBED_DIM}, classes + 1))")
    for key, shape in OPTIONAL_KEYS.items():
        value = rest.get(key)
        if isinstance(value, torch.Tensor) and value.ndim == len(shape) and all(s in (None, d) for s, d in zip(shape, value.shape, strict=True)):
            del rest[key]
    return rest, problems


def load_state(net: torch.nn.Module, checkpoint: Any, who: str, path: Path | str, expected: str) -> None:
    """Load a checkpoint's network weights into ``net`` strictly; any mismatch is one :class:`CheckpointError` line naming ``expected``."""
    state, what = model_state(checkpoint)
    if state is None:
        raise CheckpointError(f"{who}: config field 'weights': {path} holds {what}; expected {expected}")
    rest, problems = split_state(state)
    if problems:
        raise CheckpointError(f"{who}: config field 'weights': {path} does not match {expected}: {'; '.join(problems)}")
    load_strict(net, rest, who, path, expected)
