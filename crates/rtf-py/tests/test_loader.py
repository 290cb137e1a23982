"""`Dataset.loader`: rtf's loader threads as a PyTorch iterable."""

import numpy as np
import torch

import rtf


def batches(loader, epoch):
    return [(x.clone(), y.clone()) for x, y in loader.epoch(epoch)]


def test_unaugmented_batches_are_the_frames_the_readers_return(synth):
    ds = rtf.open_dataset(synth)
    split = ds.split("train")
    loader = ds.loader("train", 4, shuffle=False, augment=False, workers=2)
    assert len(loader) == -(-len(split) // 4)
    index = 0
    for x, y in loader:
        assert x.dtype == torch.float32 and y.dtype == torch.int64
        assert x.shape[1] == 4 and x.shape[0] == y.shape[0] <= 4
        for b in range(x.shape[0]):
            frame = split[index]
            index += 1
            rgb = torch.from_numpy(frame.rgb).permute(2, 0, 1).float() / 255.0
            assert torch.equal(x[b, :3], rgb)
            assert torch.equal(x[b, 3], torch.from_numpy(frame.thermal))
            assert torch.equal(y[b], torch.from_numpy(frame.label).long())
    assert index == len(split)


def test_a_seed_gives_the_same_batches_whatever_the_workers(synth):
    ds = rtf.open_dataset(synth)
    one = batches(ds.loader("train", 3, seed=7, workers=0), 1)
    two = batches(ds.loader("train", 3, seed=7, workers=2), 1)
    other = batches(ds.loader("train", 3, seed=8, workers=2), 1)
    assert len(one) == len(two) > 1
    assert all(torch.equal(a[0], b[0]) and torch.equal(a[1], b[1]) for a, b in zip(one, two))
    assert not all(torch.equal(a[0], b[0]) for a, b in zip(one, other))
    # Each iteration is the next epoch: another order.
    loader = ds.loader("train", 3, seed=7)
    first, second = [[x.clone() for x, _ in loader] for _ in range(2)]
    assert not all(torch.equal(a, b) for a, b in zip(first, second))


def test_a_bad_batch_size_is_refused(synth):
    ds = rtf.open_dataset(synth)
    try:
        ds.loader("train", 0)
    except rtf.InputError as err:
        assert "batch_size" in str(err)
    else:
        raise AssertionError("batch_size 0 was taken")
