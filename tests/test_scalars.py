"""Losses logged without a device sync (``training/scalars.py``): every step written once, in
order, at its own step; a copy not yet done holds back the later ones."""

import pytest
import torch

from warp_terrain.training.scalars import DeferredScalars


class _Event:
    """A stand-in for a CUDA event: done when the test says so."""

    def __init__(self):
        self.done = False
        self.waited = False

    def query(self):
        return self.done

    def synchronize(self):
        self.waited = True
        self.done = True


def test_cpu_values_are_written_at_once_at_their_step():
    written = []
    scalars = DeferredScalars(lambda tag, value, step: written.append((tag, value, step)))
    losses = {"l1": torch.tensor(0.25, requires_grad=True) * 2, "discriminator": torch.tensor([0.75])}
    scalars.push(10, losses)
    assert written == [("loss/l1", 0.5, 10), ("loss/discriminator", 0.75, 10)]
    assert scalars.latest == {"l1": 0.5, "discriminator": 0.75} and not scalars.pending
    scalars.push(20, {})  # nothing new: nothing written twice
    assert len(written) == 2


def test_a_pending_copy_holds_back_later_steps_until_done_or_flushed():
    written = []
    scalars = DeferredScalars(lambda tag, value, step: written.append((tag, value, step)), "train")
    first, second = _Event(), _Event()
    scalars.pending.append((1, ["a"], torch.tensor([1.0]), first))
    scalars.pending.append((2, ["a"], torch.tensor([2.0]), second))
    second.done = True
    scalars.flush(wait=False)
    assert written == []  # step 2's copy is done, but step 1 comes first
    first.done = True
    scalars.flush(wait=False)
    assert written == [("train/a", 1.0, 1), ("train/a", 2.0, 2)] and scalars.latest == {"a": 2.0}
    third = _Event()
    scalars.pending.append((3, ["a", "b"], torch.tensor([3.0, 4.0]), third))
    scalars.flush(wait=True)
    assert third.waited and written[-2:] == [("train/a", 3.0, 3), ("train/b", 4.0, 3)] and not scalars.pending


@pytest.mark.gpu
def test_cuda_losses_reach_the_writer_once_their_copy_is_done():
    written = []
    scalars = DeferredScalars(lambda tag, value, step: written.append((tag, value, step)))
    for step in range(3):
        scalars.push(step, {"l1": torch.full((), float(step), device="cuda")})
    scalars.flush(wait=True)
    assert written == [("loss/l1", 0.0, 0), ("loss/l1", 1.0, 1), ("loss/l1", 2.0, 2)]
