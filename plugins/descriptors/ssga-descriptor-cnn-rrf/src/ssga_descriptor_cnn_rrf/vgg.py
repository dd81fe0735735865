"""VGG classifiers in plain torch, with torchvision's parameter names.

torchvision cannot be installed here, so the network is rebuilt: ``features`` is the
same ``nn.Sequential`` of 3 x 3 convolutions (padding 1), ReLUs and 2 x 2 max-pools
(with a ``BatchNorm2d`` after each convolution in the ``_bn`` variants), then
``avgpool = AdaptiveAvgPool2d((pool, pool))``, then ``classifier = Linear, ReLU,
Dropout, Linear, ReLU, Dropout, Linear``. With ``width = 1``, ``hidden = 4096`` and
``pool = 7`` the state dict is torchvision's key for key and shape for shape:
``features.{0,2,5,7,10,12,14,17,19,21,24,26,28}.{weight,bias}`` and
``classifier.{0,3,6}.{weight,bias}`` for VGG16, so ``vgg16-397923af.pth`` (ImageNet)
loads strictly. Narrower widths, a smaller classifier and a smaller pool give the light
networks of the same family and the same key names.
"""

from __future__ import annotations

import torch
from torch import nn

from ssga_descriptor_cnn_rrf.layout import LAYOUTS, Arch

IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)
"""Input normalisation of torchvision's ImageNet models, used for every network here so ImageNet weights fit."""


class VGG(nn.Module):
    """A VGG classifier; ``VGG("vgg16", 1000)`` is torchvision's ``vgg16()``.

    Args:
        layout: the convolution layout (``"vgg16"``: 13 convolutions, ``"vgg11"``: 8).
        num_classes: rows of the last layer (``classifier.6``).
        width: channel multiplier of every convolution (1: torchvision's 64...512).
        hidden: width of the two hidden fully connected layers (torchvision: 4096).
        pool: side of the adaptive average pool before the classifier (torchvision: 7).
        batch_norm: a ``BatchNorm2d`` after each convolution (torchvision's ``vgg16_bn`` names).
        dropout: dropout probability of the two hidden layers.
    """

    def __init__(
        self,
        layout: Arch = "vgg16",
        num_classes: int = 1000,
        *,
        width: float = 1.0,
        hidden: int = 4096,
        pool: int = 7,
        batch_norm: bool = False,
        dropout: float = 0.5,
    ) -> None:
        super().__init__()
        layers: list[nn.Module] = []
        channels = 3
        for item in LAYOUTS[layout]:
            if item == "M":
                layers.append(nn.MaxPool2d(kernel_size=2, stride=2))
                continue
            out = max(1, round(int(item) * width))
            layers.append(nn.Conv2d(channels, out, kernel_size=3, padding=1))
            if batch_norm:
                layers.append(nn.BatchNorm2d(out))
            layers.append(nn.ReLU(inplace=True))
            channels = out
        self.features = nn.Sequential(*layers)
        self.avgpool = nn.AdaptiveAvgPool2d((pool, pool))
        self.classifier = nn.Sequential(
            nn.Linear(channels * pool * pool, hidden),
            nn.ReLU(inplace=True),
            nn.Dropout(p=dropout),
            nn.Linear(hidden, hidden),
            nn.ReLU(inplace=True),
            nn.Dropout(p=dropout),
            nn.Linear(hidden, num_classes),
        )
        # torchvision's initialisation, except the two hidden fully connected layers: torchvision
        # draws them with std 0.01, which shrinks the signal ~20x per layer at hidden = 256 and left a
        # narrow network trained from scratch on a plateau (4 flat colours: 50 % training accuracy after
        # 40 steps, against 100 % with He initialisation). Files loaded over them replace both anyway.
        for module in self.features.modules():
            if isinstance(module, nn.Conv2d):
                nn.init.kaiming_normal_(module.weight, mode="fan_out", nonlinearity="relu")
                nn.init.zeros_(module.bias)
            elif isinstance(module, nn.BatchNorm2d):
                nn.init.ones_(module.weight)
                nn.init.zeros_(module.bias)
        for i in (0, 3):
            nn.init.kaiming_normal_(self.classifier[i].weight, nonlinearity="relu")
            nn.init.zeros_(self.classifier[i].bias)
        nn.init.normal_(self.classifier[6].weight, 0.0, 0.01)
        nn.init.zeros_(self.classifier[6].bias)

    @property
    def num_classes(self) -> int:
        return self.classifier[6].out_features

    def replace_head(self, num_classes: int) -> None:
        """A new, freshly initialised last layer (``classifier.6``) with ``num_classes`` outputs."""
        old = self.classifier[6]
        head = nn.Linear(old.in_features, num_classes).to(old.weight.device)
        nn.init.normal_(head.weight, 0.0, 0.01)
        nn.init.zeros_(head.bias)
        self.classifier[6] = head

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = self.avgpool(self.features(x))
        return self.classifier(torch.flatten(x, 1))


def normalise(images: torch.Tensor) -> torch.Tensor:
    """``(B, 3, H, W)`` RGB in [0, 1] to the networks' input (ImageNet mean and std)."""
    mean = images.new_tensor(IMAGENET_MEAN).view(1, 3, 1, 1)
    std = images.new_tensor(IMAGENET_STD).view(1, 3, 1, 1)
    return (images - mean) / std
