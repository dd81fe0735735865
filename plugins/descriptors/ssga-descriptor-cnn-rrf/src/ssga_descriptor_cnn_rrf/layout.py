"""The VGG convolution layouts, without torch: the config's ``arch`` is checked against them.

Config validation and ``ssga variants --list`` / ``ssga plugins`` must not import torch
(seconds); :mod:`.vgg` builds the networks from the same table.
"""

from __future__ import annotations

from typing import Literal

LAYOUTS: dict[str, tuple[int | str, ...]] = {
    # torchvision's cfgs "A" (VGG11) and "D" (VGG16): output channels of each 3 x 3 conv, "M" a 2 x 2 max-pool.
    "vgg11": (64, "M", 128, "M", 256, 256, "M", 512, 512, "M", 512, 512, "M"),
    "vgg16": (64, 64, "M", 128, 128, "M", 256, 256, 256, "M", 512, 512, 512, "M", 512, 512, 512, "M"),
}
Arch = Literal["vgg11", "vgg16"]
