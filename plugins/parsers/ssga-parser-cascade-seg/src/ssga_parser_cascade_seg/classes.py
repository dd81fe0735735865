"""The vocabularies the networks predict: class index ``k`` is the ``k``-th name.

Both follow the CSAIL convention: the network's class ``k`` is the dataset's label
``k + 1`` (label 0, "other" in ADE20K and unused in procedural homes, is never
predicted; it is ignored in training).
"""

from __future__ import annotations

ADE20K: tuple[str, ...] = (
    'wall', 'building', 'sky', 'floor', 'tree', 'ceiling', 'road', 'bed', 'windowpane', 'grass', 'cabinet',
    'sidewalk', 'person', 'earth', 'door', 'table', 'mountain', 'plant', 'curtain', 'chair', 'car', 'water',
    'painting', 'sofa', 'shelf', 'house', 'sea', 'mirror', 'rug', 'field', 'armchair', 'seat', 'fence', 'desk',
    'rock', 'wardrobe', 'lamp', 'bathtub', 'railing', 'cushion', 'base', 'box', 'column', 'signboard',
    'chest of drawers', 'counter', 'sand', 'sink', 'skyscraper', 'fireplace', 'refrigerator', 'grandstand', 'path',
    'stairs', 'runway', 'case', 'pool table', 'pillow', 'screen door', 'stairway', 'river', 'bridge', 'bookcase',
    'blind', 'coffee table', 'toilet', 'flower', 'book', 'hill', 'bench', 'countertop', 'stove', 'palm',
    'kitchen island', 'computer', 'swivel chair', 'boat', 'bar', 'arcade machine', 'hovel', 'bus', 'towel', 'light',
    'truck', 'tower', 'chandelier', 'awning', 'streetlight', 'booth', 'television', 'airplane', 'dirt track',
    'apparel', 'pole', 'land', 'bannister', 'escalator', 'ottoman', 'bottle', 'buffet', 'poster', 'stage', 'van',
    'ship', 'fountain', 'conveyer belt', 'canopy', 'washer', 'plaything', 'swimming pool', 'stool', 'barrel',
    'basket', 'waterfall', 'tent', 'bag', 'minibike', 'cradle', 'oven', 'ball', 'food', 'step', 'tank', 'trade name',
    'microwave', 'pot', 'animal', 'bicycle', 'lake', 'dishwasher', 'screen', 'blanket', 'sculpture', 'hood',
    'sconce', 'vase', 'traffic light', 'tray', 'ashcan', 'fan', 'pier', 'crt screen', 'plate', 'monitor',
    'bulletin board', 'shower', 'radiator', 'glass', 'clock', 'flag',
)  # fmt: skip
"""ADE20K SceneParsing's 150 classes in label order (``objectInfo150``), each by its first name
("coffee table" for "coffee table, cocktail table"). CSAIL's ``object150_info.csv`` lost the
spaces of these names ("coffee;table;cocktail;table"), so its first word is not the name."""

PROCEDURAL: tuple[str, ...] = (
    "wall", "floor", "ceiling", "table", "chair", "sofa", "bed", "cabinet", "shelf", "plant", "lamp", "painting", "rug",
)  # fmt: skip
"""The procedural homes' categories in id order: class ``k`` is semantic id ``k + 1``
(``ssga_workspace_procedural.categories``, whose ids never change meaning)."""

VOCABULARIES: dict[str, tuple[str, ...]] = {"ade20k": ADE20K, "procedural": PROCEDURAL}
