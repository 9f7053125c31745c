"""Traps a new user met on the command line, each fixed: negative numbers after --transform,
two models at once, a corrupt .pcd header, a model file that holds pickled objects."""

from __future__ import annotations

import collections

import numpy as np
import pytest
import torch

from warp_terrain.cli import join_numeric_values, main


def _cloud(path):
    rng = np.random.default_rng(0)
    np.save(path, (rng.normal(size=(3000, 3)) * [5.0, 5.0, 0.05] + [5.0, 0.0, -1.8]).astype(np.float32))


def test_transform_takes_negative_numbers_without_an_equals_sign(tmp_path, capsys):
    assert join_numeric_values(["reconstruct", "a.npy", "--transform", "-5,0,0,0,0,0"]) == ["reconstruct", "a.npy", "--transform=-5,0,0,0,0,0"]
    assert join_numeric_values(["--transform", "-h"]) == ["--transform", "-h"]  # an option stays an option
    _cloud(tmp_path / "pts.npy")
    assert main(["reconstruct", str(tmp_path / "pts.npy"), "--transform", "-5,0,0,0,0,0", "--out", str(tmp_path / "a.npz"), "--no-tta"]) == 0
    assert main(["reconstruct", str(tmp_path / "pts.npy"), "--transform=-5,0,0,0,0,0", "--out", str(tmp_path / "b.npz"), "--no-tta"]) == 0
    a, b = np.load(tmp_path / "a.npz"), np.load(tmp_path / "b.npz")
    np.testing.assert_array_equal(a["height"], b["height"])
    assert a["mask"][40:80, 40:80].mean() > 0.5  # the cloud moved 5 m back: centred on the sensor


def test_two_models_at_once_are_refused(tmp_path, capsys):
    assert main(["evaluate", "--checkpoint", str(tmp_path / "x.pt"), "--pretrained", "--quick"]) == 2
    assert "--pretrained name two models: give one" in capsys.readouterr().err


def test_a_corrupt_pcd_header_is_one_short_line_naming_the_file_and_field(tmp_path, capsys):
    pytest.importorskip("pypcd4")
    bad = tmp_path / "bad.pcd"
    bad.write_text("# .PCD v0.7\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 2\nHEIGHT 1\n"
                   "VIEWPOINT 0 0 0 1 0 0 0\nPOINTS -2\nDATA ascii\n1 2 3\n4 5 6\n")
    assert main(["reconstruct", str(bad)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and len(err) < 300, err
    assert "bad.pcd" in err and "header field points" in err


class Payload:
    """Anything that is not a tensor: torch.load(weights_only=True) refuses to build it."""


def test_a_model_file_with_pickled_objects_is_refused_without_torch_advice(tmp_path, capsys):
    _cloud(tmp_path / "pts.npy")
    torch.save({"netG": collections.OrderedDict(), "model_config": {}, "meta": Payload()}, tmp_path / "evil.pt")
    assert main(["reconstruct", str(tmp_path / "pts.npy"), "--model", str(tmp_path / "evil.pt"), "--out", str(tmp_path / "m.npz")]) == 2
    err = capsys.readouterr().err
    assert "evil.pt" in err and "never loaded (weights_only=True)" in err
    assert "weights_only=False" not in err and len(err.strip().splitlines()) == 1


def test_a_missing_input_is_named_before_the_output(tmp_path, capsys):
    missing = tmp_path / "no_such_folder" / "scan.npy"
    assert main(["reconstruct", str(missing)]) == 2
    err = capsys.readouterr().err
    assert f"{str(missing)!r}: no such file" in err and "--out" not in err


def test_generate_does_not_offer_all(tmp_path, capsys):
    assert main(["generate", "2", "--out", str(tmp_path / "d"), "--terrain", "all"]) == 2
    err = capsys.readouterr().err
    assert "unknown terrain setting" in err and ", all," not in err and "octave5" in err
