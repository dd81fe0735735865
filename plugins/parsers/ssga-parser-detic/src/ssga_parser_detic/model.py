"""Detic's ResNet-50 detector in plain torch, laid out as its released checkpoints are.

The configuration is Detic's ``Detic_LCOCOI21k_CLIP_R5021k_640b32_4x_ft4x_max-size``
(base ``Base-C2_L_R5021k_640b64_4x``): CenterNet2 with a CLIP zero-shot classifier.
Module names follow the detectron2 model, so the checkpoint's ``model`` state dict loads
with strict key and shape checks:

* ``backbone.bottom_up.base``: timm's ResNet-50 (``build_p67_timm_fpn_backbone``,
  ``resnet50_in21k``), every batch norm frozen (``weight``, ``bias``, ``running_mean``,
  ``running_var``); its stages at strides 8, 16, 32 (``layer3..5`` in Detic's naming).
* ``backbone.fpn_lateral{3,4,5}``, ``backbone.fpn_output{3,4,5}``: a 256-channel FPN (sum
  fusion, no norm); ``backbone.top_block.p6/p7``: stride-2 3x3 convolutions on P5's
  output (``LastLevelP6P7_P5``, a ReLU between them).
* ``proposal_generator.centernet_head``: CenterNet as a class-agnostic proposal network
  (``ONLY_PROPOSAL``, ``WITH_AGN_HM``): four conv + GroupNorm(32) + ReLU layers on each
  of P3..P7 (``bbox_tower``), a 4-channel distance regressor (``bbox_pred``) scaled per
  level (``scales``), and an objectness heatmap (``agn_hm``).
* ``roi_heads``: a three-stage cascade (``DeticCascadeROIHeads``), each stage two fully
  connected layers of 1024 (``box_head.{k}.fc1/fc2``) on 7 x 7 ROIAlign features of P3..P5,
  a zero-shot classifier (``box_predictor.{k}.cls_score``: ``linear`` to 512, L2
  normalised, times 50, against the L2-normalised class embeddings with a zero
  background column, ``zs_weight``) and a class-agnostic box regressor (``bbox_pred``: two
  linear layers); a class-agnostic mask head (``mask_head``: four 3x3 convs, a 2x
  deconvolution, a 1x1 predictor: 28 x 28 masks from 14 x 14 features).

Inference is :func:`detect`: resize, normalise, pad, proposals, cascade, masks, back to
the image's pixels. Its constants are the config's values at test time.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from ssga_parser_detic.ops import (
    apply_deltas,
    batched_nms,
    clip_boxes,
    nms,
    paste_masks,
    pool_levels,
    resize_rgb,
    resized_shape,
)

PIXEL_MEAN = (123.675, 116.28, 103.53)
PIXEL_STD = (58.395, 57.12, 57.375)
"""``MODEL.PIXEL_MEAN`` / ``PIXEL_STD``, on RGB (``INPUT.FORMAT: RGB``) in 0..255."""

SIZE_DIVISIBILITY = 32
"""The FPN's largest input stride: images are zero-padded (after normalisation) to a multiple of it."""

FPN_CHANNELS = 256
PROPOSAL_STRIDES = (8, 16, 32, 64, 128)
"""``CENTERNET.IN_FEATURES`` p3..p7."""
ROI_STRIDES = (8, 16, 32)
"""``ROI_HEADS.IN_FEATURES`` p3..p5, for both box and mask poolers."""

PROPOSAL_SCORE_MIN = 1e-4
"""``CENTERNET.INFERENCE_TH``: heatmap values at or below it propose nothing."""
PROPOSALS_PER_LEVEL = 1000
"""``CENTERNET.PRE_NMS_TOPK_TEST``."""
PROPOSALS = 256
"""``CENTERNET.POST_NMS_TOPK_TEST``."""
PROPOSAL_NMS = 0.9
"""``CENTERNET.NMS_TH_TEST``."""

CASCADE_BOX_WEIGHTS = ((10.0, 10.0, 5.0, 5.0), (20.0, 20.0, 10.0, 10.0), (30.0, 30.0, 15.0, 15.0))
"""``ROI_BOX_CASCADE_HEAD.BBOX_REG_WEIGHTS`` (detectron2's default): one stage each."""
BOX_POOL, MASK_POOL = 7, 14
"""``ROI_BOX_HEAD`` / ``ROI_MASK_HEAD.POOLER_RESOLUTION``."""
FC_DIM = 1024
EMBED_DIM = 512
"""``ZEROSHOT_WEIGHT_DIM``: CLIP's text embedding length."""
NORM_TEMP = 50.0
"""``ROI_BOX_HEAD.NORM_TEMP``: the temperature of the cosine classifier."""
MASK_THRESHOLD = 0.5
"""``detector_postprocess``'s threshold on the pasted mask probabilities."""

RESNET50_BLOCKS = (3, 4, 6, 3)


# --------------------------------------------------------------------------- backbone


class FrozenBatchNorm2d(nn.Module):
    """Batch norm with fixed statistics and affine parameters, all four stored as buffers."""

    def __init__(self, channels: int, eps: float = 1e-5) -> None:
        super().__init__()
        self.eps = eps
        self.register_buffer("weight", torch.ones(channels))
        self.register_buffer("bias", torch.zeros(channels))
        self.register_buffer("running_mean", torch.zeros(channels))
        self.register_buffer("running_var", torch.ones(channels))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        scale = self.weight * (self.running_var + self.eps).rsqrt()
        shift = self.bias - self.running_mean * scale
        return torch.addcmul(shift[None, :, None, None], x, scale[None, :, None, None])


class Bottleneck(nn.Module):
    """timm's ResNet bottleneck: 1x1, 3x3 (carrying the stride), 1x1 to 4x the width."""

    def __init__(self, inplanes: int, planes: int, stride: int) -> None:
        super().__init__()
        out = planes * 4
        self.conv1 = nn.Conv2d(inplanes, planes, 1, bias=False)
        self.bn1 = FrozenBatchNorm2d(planes)
        self.conv2 = nn.Conv2d(planes, planes, 3, stride=stride, padding=1, bias=False)
        self.bn2 = FrozenBatchNorm2d(planes)
        self.conv3 = nn.Conv2d(planes, out, 1, bias=False)
        self.bn3 = FrozenBatchNorm2d(out)
        self.downsample = (
            nn.Sequential(nn.Conv2d(inplanes, out, 1, stride=stride, bias=False), FrozenBatchNorm2d(out))
            if stride != 1 or inplanes != out
            else None
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = F.relu(self.bn1(self.conv1(x)))
        y = F.relu(self.bn2(self.conv2(y)))
        y = self.bn3(self.conv3(y))
        return F.relu(y + (x if self.downsample is None else self.downsample(x)))


class ResNet50(nn.Module):
    """The stem and four stages; returns the outputs at strides 8, 16 and 32 (512, 1024, 2048 channels)."""

    def __init__(self) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(3, 64, 7, stride=2, padding=3, bias=False)
        self.bn1 = FrozenBatchNorm2d(64)
        inplanes = 64
        for index, (blocks, planes) in enumerate(zip(RESNET50_BLOCKS, (64, 128, 256, 512), strict=True), 1):
            stride = 1 if index == 1 else 2
            layer = nn.Sequential(*(Bottleneck(inplanes if b == 0 else planes * 4, planes, stride if b == 0 else 1) for b in range(blocks)))
            self.add_module(f"layer{index}", layer)
            inplanes = planes * 4

    def forward(self, x: torch.Tensor) -> list[torch.Tensor]:
        x = F.max_pool2d(F.relu(self.bn1(self.conv1(x))), kernel_size=3, stride=2, padding=1)
        x = self.layer1(x)
        outs = []
        for layer in (self.layer2, self.layer3, self.layer4):
            x = layer(x)
            outs.append(x)
        return outs


class TimmBackbone(nn.Module):
    """Detic's ``TIMM`` wrapper: the network is its ``base``."""

    def __init__(self) -> None:
        super().__init__()
        self.base = ResNet50()

    def forward(self, x: torch.Tensor) -> list[torch.Tensor]:
        return self.base(x)


class TopBlock(nn.Module):
    """P6 and P7 from P5's FPN output."""

    def __init__(self) -> None:
        super().__init__()
        self.p6 = nn.Conv2d(FPN_CHANNELS, FPN_CHANNELS, 3, stride=2, padding=1)
        self.p7 = nn.Conv2d(FPN_CHANNELS, FPN_CHANNELS, 3, stride=2, padding=1)

    def forward(self, p5: torch.Tensor) -> list[torch.Tensor]:
        p6 = self.p6(p5)
        return [p6, self.p7(F.relu(p6))]


class FPN(nn.Module):
    """Top-down FPN over the backbone's stride 8/16/32 outputs, then P6 and P7: ``{"p3": ..., "p7": ...}``."""

    LEVELS = (3, 4, 5)

    def __init__(self) -> None:
        super().__init__()
        self.bottom_up = TimmBackbone()
        for level, channels in zip(self.LEVELS, (512, 1024, 2048), strict=True):
            self.add_module(f"fpn_lateral{level}", nn.Conv2d(channels, FPN_CHANNELS, 1))
            self.add_module(f"fpn_output{level}", nn.Conv2d(FPN_CHANNELS, FPN_CHANNELS, 3, padding=1))
        self.top_block = TopBlock()

    def forward(self, x: torch.Tensor) -> dict[str, torch.Tensor]:
        inputs = dict(zip(self.LEVELS, self.bottom_up(x), strict=True))
        outputs: dict[int, torch.Tensor] = {}
        merged = None
        for level in reversed(self.LEVELS):
            lateral = getattr(self, f"fpn_lateral{level}")(inputs[level])
            merged = lateral if merged is None else lateral + F.interpolate(merged, scale_factor=2.0, mode="nearest")
            outputs[level] = getattr(self, f"fpn_output{level}")(merged)
        p6, p7 = self.top_block(outputs[5])
        return {**{f"p{level}": outputs[level] for level in self.LEVELS}, "p6": p6, "p7": p7}


# --------------------------------------------------------------------------- proposals


class Scale(nn.Module):
    def __init__(self) -> None:
        super().__init__()
        self.scale = nn.Parameter(torch.ones(1))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x * self.scale


class CenterNetHead(nn.Module):
    """The box branch of CenterNet's head, shared by all levels; per level the objectness logits and distances."""

    CONVS = 4

    def __init__(self) -> None:
        super().__init__()
        tower: list[nn.Module] = []
        for _ in range(self.CONVS):
            tower += [nn.Conv2d(FPN_CHANNELS, FPN_CHANNELS, 3, padding=1), nn.GroupNorm(32, FPN_CHANNELS), nn.ReLU()]
        self.bbox_tower = nn.Sequential(*tower)
        self.bbox_pred = nn.Conv2d(FPN_CHANNELS, 4, 3, padding=1)
        self.scales = nn.ModuleList(Scale() for _ in PROPOSAL_STRIDES)
        self.agn_hm = nn.Conv2d(FPN_CHANNELS, 1, 3, padding=1)

    def forward(self, features: list[torch.Tensor]) -> Iterator[tuple[torch.Tensor, torch.Tensor]]:
        for feature, scale in zip(features, self.scales, strict=True):
            tower = self.bbox_tower(feature)
            yield self.agn_hm(tower), F.relu(scale(self.bbox_pred(tower)))


class CenterNet(nn.Module):
    def __init__(self) -> None:
        super().__init__()
        self.centernet_head = CenterNetHead()

    def forward(self, features: dict[str, torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor]:
        """Proposal boxes ``(P, 4)`` (padded-image coordinates, not clipped) and scores ``(P,)``, by decreasing score.

        Each map location proposes a box from its distances to the four sides (times the
        stride) around its centre; its score is the square root of the objectness
        probability. Per level the best 1000 above 1e-4, then NMS at IoU 0.9 over all
        levels, then the 256 best (ties at the cut all kept).
        """
        levels = [features[f"p{int(math.log2(s))}"] for s in PROPOSAL_STRIDES]
        boxes, scores = [], []
        for (logits, distances), stride in zip(self.centernet_head(levels), PROPOSAL_STRIDES, strict=True):
            w = logits.shape[-1]
            heat = logits[0, 0].sigmoid().reshape(-1)
            dist = distances[0].permute(1, 2, 0).reshape(-1, 4) * stride
            candidates = torch.nonzero(heat > PROPOSAL_SCORE_MIN).squeeze(1)
            if len(candidates) > PROPOSALS_PER_LEVEL:
                candidates = candidates[heat[candidates].topk(PROPOSALS_PER_LEVEL, sorted=False).indices]
            ys, xs = candidates // w, candidates % w
            cx = (xs * stride + stride // 2).to(heat.dtype)
            cy = (ys * stride + stride // 2).to(heat.dtype)
            d = dist[candidates]
            x0, y0 = cx - d[:, 0], cy - d[:, 1]
            # A box at least 0.01 px wide and high, as CenterNet keeps them valid for the ROI heads.
            x1, y1 = torch.maximum(cx + d[:, 2], x0 + 0.01), torch.maximum(cy + d[:, 3], y0 + 0.01)
            boxes.append(torch.stack([x0, y0, x1, y1], dim=1))
            scores.append(heat[candidates].sqrt())
        box, score = torch.cat(boxes), torch.cat(scores)
        keep = nms(box, score, PROPOSAL_NMS)
        box, score = box[keep], score[keep]
        if len(score) > PROPOSALS:
            cut = torch.kthvalue(score.float().cpu(), len(score) - PROPOSALS + 1).values.item()
            kept = score >= cut
            box, score = box[kept], score[kept]
        return box, score


# --------------------------------------------------------------------------- ROI heads


class BoxHead(nn.Module):
    def __init__(self) -> None:
        super().__init__()
        self.fc1 = nn.Linear(FPN_CHANNELS * BOX_POOL * BOX_POOL, FC_DIM)
        self.fc2 = nn.Linear(FC_DIM, FC_DIM)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return F.relu(self.fc2(F.relu(self.fc1(x.flatten(1)))))


class ZeroShotClassifier(nn.Module):
    """Cosine similarity (times ``NORM_TEMP``) of a projected box feature with each class embedding.

    The class embeddings (``zs_weight``, ``(512, C + 1)``, unit columns, the last one zero
    for the background) are the vocabulary's, set by :meth:`set_vocabulary` as Detic's
    ``reset_cls_test`` does; the checkpoint's own (its training vocabulary) is not kept,
    so ``zs_weight`` is not part of this module's state dict.
    """

    def __init__(self) -> None:
        super().__init__()
        self.linear = nn.Linear(FC_DIM, EMBED_DIM)
        self.register_buffer("zs_weight", torch.zeros(EMBED_DIM, 1), persistent=False)

    def set_vocabulary(self, embeddings: torch.Tensor) -> None:
        """``embeddings``: ``(C, 512)``, one row per class."""
        weight = torch.cat([embeddings.t().float(), embeddings.new_zeros((EMBED_DIM, 1), dtype=torch.float32)], dim=1)
        self.zs_weight = F.normalize(weight, p=2, dim=0).to(self.linear.weight.device)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return NORM_TEMP * F.normalize(self.linear(x), p=2, dim=1) @ self.zs_weight


class BoxPredictor(nn.Module):
    def __init__(self) -> None:
        super().__init__()
        self.cls_score = ZeroShotClassifier()
        self.bbox_pred = nn.Sequential(nn.Linear(FC_DIM, FC_DIM), nn.ReLU(), nn.Linear(FC_DIM, 4))

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return self.cls_score(x), self.bbox_pred(x)


class MaskHead(nn.Module):
    CONVS = 4

    def __init__(self) -> None:
        super().__init__()
        for k in range(1, self.CONVS + 1):
            self.add_module(f"mask_fcn{k}", nn.Conv2d(FPN_CHANNELS, FPN_CHANNELS, 3, padding=1))
        self.deconv = nn.ConvTranspose2d(FPN_CHANNELS, FPN_CHANNELS, 2, stride=2)
        self.predictor = nn.Conv2d(FPN_CHANNELS, 1, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        for k in range(1, self.CONVS + 1):
            x = F.relu(getattr(self, f"mask_fcn{k}")(x))
        return self.predictor(F.relu(self.deconv(x)))


class CascadeROIHeads(nn.Module):
    def __init__(self) -> None:
        super().__init__()
        self.box_head = nn.ModuleList(BoxHead() for _ in CASCADE_BOX_WEIGHTS)
        self.box_predictor = nn.ModuleList(BoxPredictor() for _ in CASCADE_BOX_WEIGHTS)
        self.mask_head = MaskHead()


@dataclass(frozen=True)
class Settings:
    """What inference may change; the defaults are Detic's demo on the config above."""

    score_threshold: float = 0.5
    """``ROI_HEADS.SCORE_THRESH_TEST`` as the demo sets it (``--confidence-threshold``)."""
    nms_threshold: float = 0.5
    """``ROI_HEADS.NMS_THRESH_TEST``, per class."""
    max_detections: int = 300
    """``TEST.DETECTIONS_PER_IMAGE``."""
    one_class_per_proposal: bool = True
    """``ROI_HEADS.ONE_CLASS_PER_PROPOSAL``, on in the demo: each box keeps only its best class's score."""
    resize: str = "max-size"
    size: int = 640
    max_size: int = 1333


@dataclass(frozen=True)
class Detections:
    """Detections in an image's own pixels, by decreasing score.

    Attributes:
        boxes: ``(N, 4)`` float32 ``x0, y0, x1, y1``, pixel ``i`` spanning ``[i, i + 1)``.
        scores: ``(N,)`` float32.
        classes: ``(N,)`` int64 indices into the vocabulary.
        masks: ``(N, H, W)`` bool.
    """

    boxes: np.ndarray
    scores: np.ndarray
    classes: np.ndarray
    masks: np.ndarray

    def __len__(self) -> int:
        return len(self.scores)


class DeticR50(nn.Module):
    """The whole detector; :meth:`set_vocabulary` before :func:`detect`."""

    def __init__(self) -> None:
        super().__init__()
        self.backbone = FPN()
        self.proposal_generator = CenterNet()
        self.roi_heads = CascadeROIHeads()

    def set_vocabulary(self, embeddings: torch.Tensor) -> None:
        for predictor in self.roi_heads.box_predictor:
            predictor.cls_score.set_vocabulary(embeddings)

    @property
    def num_classes(self) -> int:
        return self.roi_heads.box_predictor[0].cls_score.zs_weight.shape[1] - 1

    def forward(self, image: torch.Tensor, image_size: tuple[int, int], settings: Settings) -> tuple[torch.Tensor, ...]:
        """Detections of one normalised, padded ``(1, 3, H, W)`` image whose content is ``image_size``.

        Returns boxes ``(N, 4)`` in that image's coordinates, scores ``(N,)``, classes
        ``(N,)`` and mask probabilities ``(N, 28, 28)``, by decreasing score.
        """
        features = self.backbone(image)
        proposals, proposal_scores = self.proposal_generator(features)
        roi_features = [features[f"p{int(math.log2(s))}"] for s in ROI_STRIDES]
        boxes, probs = proposals, []  # the first stage takes the proposals as they are, unclipped
        for head, predictor, weights in zip(self.roi_heads.box_head, self.roi_heads.box_predictor, CASCADE_BOX_WEIGHTS, strict=True):
            logits, deltas = predictor(head(pool_levels(roi_features, boxes, list(ROI_STRIDES), BOX_POOL)))
            probs.append(logits.sigmoid())  # Detic's classifier is trained with sigmoid cross-entropy
            # Each stage refines the previous stage's boxes, clipped to the image; the last stage's are the detections'.
            boxes = clip_boxes(apply_deltas(deltas, boxes, weights), image_size)
        # The stages' mean class probability, then its geometric mean with the proposal's
        # score (MULT_PROPOSAL_SCORE); the last column is the background's.
        scores = torch.sqrt(torch.stack(probs).mean(dim=0) * proposal_scores[:, None])[:, :-1]
        if settings.one_class_per_proposal:
            scores = scores * (scores == scores.max(dim=1, keepdim=True).values)
        return self._select(boxes, scores, roi_features, settings)

    def _select(self, boxes: torch.Tensor, scores: torch.Tensor, roi_features: list[torch.Tensor], settings: Settings) -> tuple[torch.Tensor, ...]:
        """detectron2's ``fast_rcnn_inference``: threshold, NMS per class, the best ``max_detections``; then masks."""
        finite = torch.isfinite(boxes).all(dim=1) & torch.isfinite(scores).all(dim=1)
        boxes, scores = boxes[finite], scores[finite]
        rows, classes = torch.nonzero(scores > settings.score_threshold, as_tuple=True)
        boxes, scores = boxes[rows], scores[rows, classes]
        keep = batched_nms(boxes, scores, classes, settings.nms_threshold)[: settings.max_detections]
        boxes, scores, classes = boxes[keep], scores[keep], classes[keep]
        masks = self.roi_heads.mask_head(pool_levels(roi_features, boxes, list(ROI_STRIDES), MASK_POOL))
        return boxes, scores, classes, masks[:, 0].sigmoid()


def preprocess(rgb: np.ndarray, settings: Settings, device: torch.device) -> tuple[torch.Tensor, tuple[int, int]]:
    """The resized, normalised image zero-padded to a multiple of 32, and its resized ``(height, width)``."""
    shape = resized_shape(rgb.shape[:2], settings.resize, settings.size, settings.max_size)
    image = torch.from_numpy(np.array(resize_rgb(rgb, shape), dtype=np.uint8)).to(device).permute(2, 0, 1).float()
    mean = torch.tensor(PIXEL_MEAN, device=device)[:, None, None]
    std = torch.tensor(PIXEL_STD, device=device)[:, None, None]
    h, w = shape
    padded = image.new_zeros((1, 3, -(-h // SIZE_DIVISIBILITY) * SIZE_DIVISIBILITY, -(-w // SIZE_DIVISIBILITY) * SIZE_DIVISIBILITY))
    padded[0, :, :h, :w] = (image - mean) / std
    return padded, shape


def detect(net: DeticR50, rgb: np.ndarray, settings: Settings) -> Detections:
    """Detic's detections of a uint8 ``(H, W, 3)`` RGB image, in its own pixels (detectron2's ``detector_postprocess``)."""
    device = next(net.parameters()).device
    h, w = rgb.shape[:2]
    image, shape = preprocess(rgb, settings, device)
    with torch.inference_mode():
        boxes, scores, classes, masks = net(image, shape, settings)
        boxes = boxes * torch.tensor([w / shape[1], h / shape[0]] * 2, device=device)
        boxes = clip_boxes(boxes, (h, w))
        nonempty = (boxes[:, 2] > boxes[:, 0]) & (boxes[:, 3] > boxes[:, 1])
        boxes, scores, classes, masks = boxes[nonempty], scores[nonempty], classes[nonempty], masks[nonempty]
        pasted = paste_masks(masks, boxes, (h, w), MASK_THRESHOLD)
    return Detections(
        boxes=boxes.float().cpu().numpy(),
        scores=scores.float().cpu().numpy(),
        classes=classes.cpu().numpy().astype(np.int64),
        masks=pasted.cpu().numpy(),
    )


def init_random(net: DeticR50, seed: int) -> DeticR50:
    """Seeded random weights (tests and timing only).

    torch's default initialisation, except CenterNet's distance regressor starts at 8
    (its own initialisation), so proposals are boxes of about 16 strides rather than
    points, and the later stages see boxes of realistic sizes.
    """
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        for module in net.modules():
            if module is not net and hasattr(module, "reset_parameters"):
                module.reset_parameters()
        nn.init.constant_(net.proposal_generator.centernet_head.bbox_pred.bias, 8.0)
    return net
