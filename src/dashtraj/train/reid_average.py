"""Weight averaging of ReID training checkpoints (needs the ``.[train]`` extra: torch).

Averaging the weights of a few checkpoints along one training trajectory — the ends of
successive learning-rate cycles, each continuing from the last — is stochastic weight
averaging (Izmailov et al., "Averaging Weights Leads to Wider Optima and Better
Generalization", UAI 2018): the mean lies nearer the centre of the flat region the cycles
circle, and usually generalises better than any one of them, at no cost at run time (the
averaged network is one network of the same size and speed).

Every floating-point tensor of the state dicts (weights and the BatchNorm running
statistics) is the plain mean; integer buffers (BatchNorm's ``num_batches_tracked``) are
the first checkpoint's. The BatchNorm statistics are averaged, not recomputed: the
checkpoints averaged here are close (consecutive cycles of one run), and their mean
statistics serve the mean weights (for the shipped ReID model, statistics recomputed on
8,192 training images scored a fraction lower: README, stage 8). The output is a
checkpoint in a run's ``best.pt`` format (``model``, ``recipe``, ``num_classes``,
``epoch``, ``seed``) plus ``averaged_from`` (each input's path, sha256 and epoch), so
`dashtraj reid export` takes it as it takes a run's.
"""

from __future__ import annotations

from pathlib import Path

from dashtraj.digest import file_sha256
from dashtraj.errors import DashtrajError


class AverageError(DashtrajError):
    """Checkpoints that cannot be averaged; the message names the file."""


def _load(path: Path) -> dict:
    import torch

    if not path.is_file():
        raise AverageError(f"{path}: no such checkpoint")
    try:
        ck = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as e:  # a pickle or zip error of any kind: not a checkpoint
        raise AverageError(f"{path}: not a torch checkpoint ({type(e).__name__}: {e})") from e
    if not isinstance(ck, dict) or not all(k in ck for k in ("model", "recipe", "num_classes")):
        raise AverageError(f"{path}: not a dashtraj ReID checkpoint (no model, recipe and "
                           "num_classes: give a run's best.pt or last.pt)")
    return ck


def _network(ck: dict) -> tuple:
    r = ck["recipe"]
    return r.get("model"), r.get("height"), r.get("width"), int(ck["num_classes"])


def average_checkpoints(paths) -> dict:
    """The mean of two or more checkpoints of one network, as a checkpoint dict.

    Args:
        paths: ``best.pt`` / ``last.pt`` files of dashtraj ReID runs (`dashtraj reid
            train`), all of the same backbone, input size and number of training classes.

    Raises:
        AverageError: fewer than two paths, a path given twice, a file that is missing or
            not a checkpoint, or a checkpoint of another network (backbone, input size,
            classes, or a tensor's name or shape), naming the file.
    """
    import torch

    ps = [Path(p) for p in paths]
    if len(ps) < 2:
        raise AverageError("average needs at least two checkpoints")
    seen: dict[Path, Path] = {}
    for p in ps:
        key = p.resolve()
        if key in seen:
            raise AverageError(f"{p}: given twice (also as {seen[key]}); each checkpoint once")
        seen[key] = p
    cks = [_load(p) for p in ps]
    first, net = cks[0], _network(cks[0])
    ref = first["model"]
    for p, ck in zip(ps[1:], cks[1:], strict=True):
        if _network(ck) != net:
            raise AverageError(f"{p}: another network (backbone, height, width, classes "
                               f"{_network(ck)}) than {ps[0]} ({net})")
        sd = ck["model"]
        if sd.keys() != ref.keys():
            extra = sorted(set(sd) ^ set(ref))[:3]
            raise AverageError(f"{p}: its tensors differ from {ps[0]}'s by name ({extra} ...)")
        for k, v in sd.items():
            if v.shape != ref[k].shape or v.dtype != ref[k].dtype:
                raise AverageError(f"{p}: tensor {k} is {v.dtype} {tuple(v.shape)}, "
                                   f"{ps[0]} has {ref[k].dtype} {tuple(ref[k].shape)}")
    mean = {}
    for k, v in ref.items():
        if v.is_floating_point():
            acc = torch.zeros(v.shape, dtype=torch.float64)
            for ck in cks:
                acc += ck["model"][k].to(torch.float64)
            mean[k] = (acc / len(cks)).to(v.dtype)
        else:
            mean[k] = v.clone()
    epochs = [ck.get("epoch") for ck in cks]
    return {"model": mean, "recipe": first["recipe"], "num_classes": first["num_classes"],
            "epoch": "average of epochs " + ", ".join(str(e) for e in epochs),
            "seed": first.get("seed"), "val": {},
            "averaged_from": [{"path": str(p), "sha256": file_sha256(p), "epoch": e}
                              for p, e in zip(ps, epochs, strict=True)]}


def write_average(paths, out: str | Path) -> dict:
    """`average_checkpoints` saved to ``out`` (written as given: the caller makes it
    atomic); returns the checkpoint dict."""
    import torch

    ck = average_checkpoints(paths)
    torch.save(ck, out)
    return ck
