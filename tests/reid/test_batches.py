"""The training batches (`dashtraj.reid.train.epoch_batches`) and the colour-grouped
triplet batches (`Recipe.group_batches`, `colour_groups`); numpy only, no torch."""
import hashlib
import json
from dataclasses import replace

import numpy as np
import pytest

from dashtraj.reid.train import RECIPES, TrainError, colour_groups, epoch_batches

K, P = 4, 8  # images per identity, identities per batch


def _labels(n_ids: int = 48, seed: int = 5) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.repeat(np.arange(n_ids), rng.integers(2, 30, size=n_ids))


def _recipe(**kw):
    return replace(RECIPES["cpu"], batch_size=K * P, instances=K, **kw)


def _digest(batches) -> str:
    return hashlib.sha256(np.concatenate(batches).tobytes()).hexdigest()[:16]


def test_triplet_batches_are_p_identities_of_k_images_and_unchanged_by_the_grouping_code():
    labels = _labels(40)
    r = replace(RECIPES["cpu"], batch_size=32, instances=4)
    batches = [epoch_batches(labels, r, 7, ep) for ep in range(3)]
    for b in batches[0]:
        ids = labels[b].reshape(8, 4)
        assert (ids == ids[:, :1]).all() and len(set(ids[:, 0])) == 8
    # the digests of the batches before `group_batches` existed (commit b31ec62): runs
    # started then resume with the same batches
    assert [_digest(b) for b in batches] == ["25fb6d94a14148cd", "a67bb234305a8b45",
                                             "3ece1515a7a25453"]
    # off, the groups are not read and no number is drawn for them
    groups = np.arange(40) % 3
    assert _digest(epoch_batches(labels, r, 7, 0, groups)) == "25fb6d94a14148cd"


@pytest.mark.parametrize("share", [0.5, 1.0])
def test_grouped_batches_hold_one_colour_each(share):
    labels = _labels(48)
    groups = np.arange(48) % 3  # three colours of 16 identities, 2 batches' worth each
    r = _recipe(triplet=True, group_batches=share)
    batches = epoch_batches(labels, r, 3, 0, groups)
    plain = epoch_batches(labels, _recipe(triplet=True), 3, 0)
    single = [len(set(groups[labels[b]])) == 1 for b in batches]
    for b in batches:  # still P distinct identities of K images each
        ids = labels[b].reshape(P, K)
        assert (ids == ids[:, :1]).all() and len(set(ids[:, 0])) == P
    # random batches of 8 out of 48 identities in 3 colours are almost never one colour
    assert sum(len(set(groups[labels[b]])) == 1 for b in plain) <= 1
    assert sum(single) >= (0.3 if share < 1 else 0.8) * len(batches)
    if share < 1:
        assert not all(single)
    # nearly every image still drawn: only partial batches are lost
    assert sum(map(len, batches)) >= 0.9 * sum(map(len, plain))
    assert _digest(batches) == _digest(epoch_batches(labels, r, 3, 0, groups))  # seeded
    assert _digest(batches) != _digest(epoch_batches(labels, r, 4, 0, groups))


def test_a_colour_smaller_than_a_batch_joins_the_mixed_batches():
    labels = _labels(48)
    groups = np.where(np.arange(48) < 4, 1, 0)  # colour 1: 4 identities, under P = 8
    batches = epoch_batches(labels, _recipe(triplet=True, group_batches=1.0), 0, 0, groups)
    small = set(np.flatnonzero(groups == 1))
    drawn = {int(c) for b in batches for c in labels[b]}
    assert small <= drawn
    assert not any(len(set(groups[labels[b]])) == 1 and groups[labels[b][0]] == 1
                   for b in batches)


def test_grouping_needs_groups():
    with pytest.raises(ValueError, match="groups"):
        epoch_batches(_labels(), _recipe(triplet=True, group_batches=0.5), 0, 0)


def test_colour_groups_from_reid_json(tmp_path):
    ids = [{"id": 1, "key": "vehicle.audi.a2/black"}, {"id": 2, "key": "vehicle.bmw.x5/red"},
           {"id": 3, "key": "vehicle.audi.tt/black"}, {"id": 4, "key": "vehicle.a/light blue"}]
    (tmp_path / "reid.json").write_text(json.dumps({"ids": ids}))
    assert colour_groups(tmp_path, [1, 2, 3, 4]).tolist() == [0, 2, 0, 1]
    assert colour_groups(tmp_path, [2, 4]).tolist() == [1, 0]  # numbered over the classes
    with pytest.raises(TrainError, match="lists no identity 9"):
        colour_groups(tmp_path, [1, 9])
    (tmp_path / "reid.json").write_text(json.dumps({"cameras": 3}))
    with pytest.raises(TrainError, match="no identity keys"):
        colour_groups(tmp_path, [1])
    with pytest.raises(TrainError, match=r"reid\.json missing"):
        colour_groups(tmp_path / "elsewhere", [1])
