"""Which checkpoint ``train.resume`` continues from (``training/checkpoint.py`` ``resolve_resume``):
every accepted spelling, each place a checkpoint can be named, and the error naming the path
that is missing. Only slow training tests reached it before (mutation testing, docs/mutation.md)."""

from pathlib import Path

import pytest

from warp_terrain.training.checkpoint import LATEST, resolve_resume


def _run(tmp_path: Path, name: str = "run") -> tuple[Path, Path]:
    run_dir = tmp_path / name
    (run_dir / "checkpoints").mkdir(parents=True)
    latest = run_dir / "checkpoints" / LATEST
    latest.write_bytes(b"x")
    return run_dir, latest


@pytest.mark.parametrize("off", ["false", "False", "NO", "0", "none", "", "  false  "])
def test_off_spellings_start_afresh(tmp_path, off):
    run_dir, _ = _run(tmp_path)
    assert resolve_resume(off, run_dir) is None


@pytest.mark.parametrize("on", ["true", "TRUE", "Yes", "1", " true "])
def test_on_spellings_continue_the_run_folders_latest(tmp_path, on):
    run_dir, latest = _run(tmp_path)
    assert resolve_resume(on, run_dir) == latest


def test_true_without_a_checkpoint_names_the_path_it_looked_for(tmp_path):
    empty = tmp_path / "fresh"
    empty.mkdir()
    expected = str(empty / "checkpoints" / LATEST)
    with pytest.raises(ValueError, match="train.resume=true: no checkpoint at") as err:
        resolve_resume("true", empty)
    assert repr(expected) in str(err.value) and "hydra.run.dir" in str(err.value)


def test_a_file_a_run_folder_or_a_checkpoints_folder(tmp_path):
    other, latest = _run(tmp_path, "other")
    here = tmp_path / "here"
    here.mkdir()
    assert resolve_resume(str(latest), here) == latest  # a checkpoint file
    assert resolve_resume(str(other), here) == latest  # a run folder: its checkpoints/latest.pt
    assert resolve_resume(str(other / "checkpoints"), here) == latest  # the checkpoints folder itself
    best = other / "checkpoints" / "best.pt"
    best.write_bytes(b"y")
    assert resolve_resume(str(best), here) == best


def test_a_home_relative_path_is_expanded(tmp_path, monkeypatch):
    monkeypatch.setenv("HOME", str(tmp_path))
    _, latest = _run(tmp_path, "home_run")
    assert resolve_resume("~/home_run", tmp_path / "elsewhere") == latest


@pytest.mark.parametrize("missing", ["nowhere.pt", "nowhere_dir"])
def test_a_missing_checkpoint_names_the_value_and_the_path(tmp_path, missing):
    value = str(tmp_path / missing)
    with pytest.raises(ValueError) as err:
        resolve_resume(value, tmp_path)
    assert f"train.resume={value!r}: no checkpoint at {value!r}" == str(err.value)


def test_a_folder_without_a_checkpoint_names_the_file_it_expected(tmp_path):
    folder = tmp_path / "bare"
    folder.mkdir()
    with pytest.raises(ValueError) as err:
        resolve_resume(str(folder), tmp_path)
    assert repr(str(folder / LATEST)) in str(err.value)
