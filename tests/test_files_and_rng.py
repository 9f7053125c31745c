"""Known answers for the small pieces everything rests on: torch files, RNG state, the lifting
of a 2-D fill to a batched predictor. Written against surviving mutants of `make mutation`
(each test here failed on at least one of them)."""

from __future__ import annotations

import pickle
import random

import numpy as np
import pytest
import torch

from warp_terrain.core.torchfile import atomic_save, load_checkpoint, read_error
from warp_terrain.evaluation.baselines import _per_map, plane_fill
from warp_terrain.training.checkpoint import rng_state, set_rng_state


# ------------------------------------------------------------------------------ torch files
def test_a_saved_file_loads_back_bit_for_bit_on_the_cpu(tmp_path):
    state = {"w": torch.randn(3, 4, dtype=torch.float64), "h": torch.arange(5, dtype=torch.float16), "step": 7, "name": "x"}
    atomic_save(state, tmp_path / "a.pt")
    back = load_checkpoint(tmp_path / "a.pt")
    assert back.keys() == state.keys() and back["step"] == 7 and back["name"] == "x"
    for key in ("w", "h"):
        assert back[key].dtype == state[key].dtype and back[key].device.type == "cpu"
        assert torch.equal(back[key], state[key])
    meta = load_checkpoint(tmp_path / "a.pt", map_location="meta")  # map_location is passed on
    assert meta["w"].device.type == "meta" and meta["w"].shape == (3, 4)


def test_load_checkpoint_names_a_missing_file_and_an_unreadable_one(tmp_path):
    missing = tmp_path / "none.pt"
    with pytest.raises(ValueError) as err:
        load_checkpoint(missing)
    assert str(err.value) == f"checkpoint {str(missing)!r} does not exist"
    garbage = tmp_path / "garbage.pt"
    garbage.write_bytes(b"not a torch file")
    with pytest.raises(ValueError) as err:
        load_checkpoint(garbage)
    message = str(err.value)
    assert message.startswith(f"checkpoint {str(garbage)!r} cannot be read (") and message.endswith(")")
    assert "does not exist" not in message


class _Code:
    def __reduce__(self):
        return (print, ("never",))


def test_load_checkpoint_refuses_pickled_code_with_a_plain_reason(tmp_path):
    path = tmp_path / "code.pt"
    torch.save({"x": _Code()}, path)
    with pytest.raises(ValueError) as err:
        load_checkpoint(path)
    assert "not a file of plain tensors: it holds objects or code that are never loaded (weights_only=True)" in str(err.value)
    assert "weights_only=False" not in str(err.value)  # never torch's advice to unpickle it


def test_read_error_keeps_the_first_line_of_a_message_at_most_200_characters():
    assert read_error(pickle.UnpicklingError("bad")) == (
        "not a file of plain tensors: it holds objects or code that are never loaded (weights_only=True)")
    assert read_error(RuntimeError("Weights only load failed: weights_only ...")).startswith("not a file of plain tensors")
    assert read_error(RuntimeError("first line\nsecond line")) == "RuntimeError: first line"
    assert read_error(OSError("  padded  ")) == "OSError: padded"
    assert read_error(EOFError()) == "EOFError"  # no message: the type alone
    assert read_error(ValueError("y" * 300)) == "ValueError: " + "y" * 200


# ------------------------------------------------------------------------------ RNG state
def test_rng_state_restores_torch_numpy_and_python_draws_exactly():
    state = rng_state()
    want = (torch.rand(5), np.random.random(5), [random.random() for _ in range(5)], random.gauss(0.0, 1.0))
    torch.rand(3), np.random.random(3), random.random()  # move every generator on
    set_rng_state(state)
    got = (torch.rand(5), np.random.random(5), [random.random() for _ in range(5)], random.gauss(0.0, 1.0))
    assert torch.equal(got[0], want[0])
    assert np.array_equal(got[1], want[1])
    assert got[2] == want[2] and got[3] == want[3]


def test_rng_state_survives_a_weights_only_file(tmp_path):
    np.random.seed(3)
    random.seed(3)
    torch.manual_seed(3)
    random.gauss(0.0, 1.0)  # python's generator caches the second Gaussian: part of the state
    atomic_save({"rng": rng_state()}, tmp_path / "rng.pt")
    want = (torch.randn(4), np.random.standard_normal(4), random.gauss(0.0, 1.0))
    set_rng_state(load_checkpoint(tmp_path / "rng.pt")["rng"])
    got = (torch.randn(4), np.random.standard_normal(4), random.gauss(0.0, 1.0))
    assert torch.equal(got[0], want[0]) and np.array_equal(got[1], want[1]) and got[2] == want[2]


# ------------------------------------------------------------------------------ 2-D fills, batched
def test_per_map_fills_each_map_keeps_observed_cells_and_skips_empty_and_full_maps():
    calls = []

    def _offset_fill_(z, known):
        """A known 2-D fill: every cell the mean observed height plus 1."""
        calls.append(int(known.sum()))
        assert z.dtype == np.float64 and known.dtype == bool
        return np.full(z.shape, z[known].mean() + 1.0)

    fill = _per_map(_offset_fill_)
    assert fill.__name__ == "offset_fill_" and fill.__doc__ == _offset_fill_.__doc__  # named as the fill, less its leading "_"
    scan = torch.zeros(4, 1, 4, 4)
    mask = torch.zeros(4, 1, 4, 4)
    scan[0], mask[0] = 5.0, 1.0  # every cell observed: returned as it is, fill not called
    scan[1, 0, 0, :2], mask[1, 0, 0, :2] = torch.tensor([1.0, 3.0]), 1.0  # two cells: mean 2
    # map 2: no observed cell (zeros); map 3 after it is filled all the same
    scan[3, 0, 2, 2], mask[3, 0, 2, 2] = -1.0, 1.0
    out = fill(scan, mask)
    assert calls == [2, 1]
    assert out.dtype == torch.float32 and out.shape == scan.shape
    assert torch.equal(out[0, 0], torch.full((4, 4), 5.0))
    want1 = torch.full((4, 4), 3.0)
    want1[0, :2] = torch.tensor([1.0, 3.0])
    assert torch.equal(out[1, 0], want1)
    assert torch.equal(out[2, 0], torch.zeros(4, 4))
    want3 = torch.zeros(4, 4)
    want3[2, 2] = -1.0
    assert torch.equal(out[3, 0], want3)
    with pytest.raises(ValueError, match="mask"):
        fill(scan, mask[:, :, :3])


def test_plane_fill_fits_three_cells_exactly_and_copies_the_nearest_below_three():
    i, j = np.indices((9, 9), dtype=np.float64)
    plane = torch.from_numpy(0.3 * i - 0.2 * j + 1.5).float()[None, None]
    mask = torch.zeros(1, 1, 9, 9)
    mask[0, 0, 1, 1] = mask[0, 0, 1, 7] = mask[0, 0, 7, 4] = 1.0  # three cells, not in a line
    torch.testing.assert_close(plane_fill(plane * mask, mask), plane, rtol=0, atol=1e-5)
    mask[0, 0, 7, 4] = 0.0  # two cells: no plane; each cell takes its nearest observed height
    out = plane_fill(plane * mask, mask)[0, 0]
    assert out[0, 0] == plane[0, 0, 1, 1] and out[8, 8] == plane[0, 0, 1, 7] and out[0, 8] == plane[0, 0, 1, 7]


def test_atomic_save_names_the_missing_folder(tmp_path):
    missing = tmp_path / "nowhere"
    with pytest.raises(ValueError) as err:
        atomic_save({"x": torch.zeros(1)}, missing / "model.pt")
    assert str(err.value) == f"checkpoint folder {str(missing)!r} does not exist"
    assert not missing.exists()


def test_a_temporary_removed_meanwhile_is_not_an_error(tmp_path, monkeypatch):
    """Two processes cleaning one folder: a stale file listed by one and deleted by the other
    before its own unlink must not make the first fail."""
    from pathlib import Path

    from warp_terrain.training.checkpoint import remove_stale_temporaries

    (tmp_path / ".latest.pt.abcd.pt").write_bytes(b"x")
    real_unlink = Path.unlink

    def raced(self, missing_ok=False):
        real_unlink(self)  # the other process got there first
        return real_unlink(self, missing_ok=missing_ok)

    monkeypatch.setattr(Path, "unlink", raced)
    assert [p.name for p in remove_stale_temporaries(tmp_path)] == [".latest.pt.abcd.pt"]
    assert not (tmp_path / ".latest.pt.abcd.pt").exists()
