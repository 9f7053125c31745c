"""``warp-terrain gpu-check``: the quick run on this machine (CPU rows PASS, CUDA rows SKIP with
the reason where there is no CUDA device), a deliberately broken run (exit 1, FAIL in the
table), the comparisons the CUDA rows use (tested on doctored CPU batches), the time limit and
bad arguments."""

from __future__ import annotations

import contextlib
import io
import json
import platform
import subprocess
import sys
import threading
import time

import numpy as np
import pytest
import torch
import warp as wp
from conftest import ROOT, tiny_sim

import warp_terrain as wt
from warp_terrain.bench import gpucheck
from warp_terrain.cli import main
from warp_terrain.cli.gpucheck import GROUPS as CLI_GROUPS
from warp_terrain.training.config import RunConfig

CUDA_REASON = gpucheck.cuda_unavailable_reason()
CUDA = CUDA_REASON is None
KERNEL_FILES = sorted(p.stem for p in (ROOT / "kernels").glob("*.py") if p.stem != "__init__")
#: (check, device kind) of a quick run, in order: CPU and CUDA consistency, CUDA throughput
#: first, the CPU's, then the process split
QUICK_ROWS = [
    ("compile", "cpu"), ("compile", "cuda"), ("repeat", "cpu"), ("repeat", "cuda"), ("poison", "cpu"), ("poison", "cuda"),
    ("walks", "cpu"), ("walks", "cuda"), ("cuda_vs_cpu", "cuda"), ("capture", "cpu"), ("capture", "cuda"), ("no_sync", "cuda"),
    ("stream b=1", "cuda"), ("stream b=8", "cuda"), ("switches b=8", "cuda"), ("train b=8", "cuda"),
    ("stream b=1", "cpu"), ("stream b=8", "cpu"), ("switches b=2", "cpu"), ("train b=8", "cpu"),
    ("process_split", "cpu"),
]
REPORT_KEYS = {"tool", "warp_terrain", "quick", "groups", "time_limit_s", "elapsed_s", "timed_out", "complete", "criteria", "plan",
               "environment", "checks", "counts", "ok"}
ROW_KEYS = {"name", "group", "device", "status", "seconds", "detail", "reason", "figures"}


def run_cli(*args: str) -> tuple[int, str]:
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        code = main(["gpu-check", *args])
    return code, out.getvalue()


def table_line(stdout: str, name: str, device: str) -> str:
    lines = [line for line in stdout.splitlines() if line.split("  ")[0].strip() == name and f"  {device}" in line]
    assert len(lines) == 1, (name, device, stdout)
    return lines[0]


# ------------------------------------------------------------------------------ the quick run
@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    path = tmp_path_factory.mktemp("gpucheck") / "report.json"
    code, stdout = run_cli("--quick", "--json", str(path), "-q")
    return code, stdout, json.loads(path.read_text())


@pytest.mark.slow
def test_the_quick_run_passes_here_and_skips_cuda_with_its_reason(quick):
    code, stdout, report = quick
    assert code == 0
    assert set(report) == REPORT_KEYS
    assert report["quick"] is True and report["ok"] is True and report["complete"] is True and report["timed_out"] is False
    assert report["groups"] == list(gpucheck.GROUPS) and report["time_limit_s"] == 420.0
    assert 0 < report["elapsed_s"] < 420
    rows = report["checks"]
    assert [(r["name"], r["device"].split(":")[0]) for r in rows] == QUICK_ROWS
    for r in rows:
        assert set(r) == ROW_KEYS
        if r["device"] == "cpu" or CUDA:
            assert (r["status"], r["reason"]) == ("PASS", None), r
            assert r["detail"] and r["seconds"] > 0
        else:
            assert (r["status"], r["reason"], r["figures"], r["seconds"]) == ("SKIP", CUDA_REASON, {}, 0.0)
            assert "CUDA" in r["reason"]
    statuses = [r["status"] for r in rows]
    assert report["counts"] == {s: statuses.count(s) for s in ("PASS", "FAIL", "SKIP")}
    assert report["counts"]["PASS"] == (len(rows) if CUDA else 10)

    env = report["environment"]
    assert (env["python"], env["torch"], env["warp"], env["warp_terrain"]) == (platform.python_version(), torch.__version__,
                                                                                 wp.config.version, wt.__version__)
    assert env["cuda"] is CUDA and env["cuda_reason"] == CUDA_REASON and "cpu" in env["warp_devices"]
    assert len(env["gpus"]) == (torch.cuda.device_count() if CUDA else 0)


@pytest.mark.slow
def test_the_quick_run_records_every_figure(quick):
    _, _, report = quick
    rows = {(r["name"], r["device"]): r["figures"] for r in report["checks"] if r["device"] == "cpu"}
    compiled = rows["compile", "cpu"]
    assert sorted(compiled["seconds"]) == KERNEL_FILES and compiled["modules"] == len(KERNEL_FILES)
    assert compiled["total_s"] == pytest.approx(sum(compiled["seconds"].values()))
    assert compiled["kernels"] == sum(compiled["kernels_per_module"].values()) > 0
    without_clutter = [a for a in gpucheck.BATCH_ARRAYS if a != "target_visible"]
    for name in ("repeat", "poison"):
        assert set(rows[name, "cpu"]) == {"octave5", "wide"}
        assert rows[name, "cpu"]["octave5"]["differing_values"] == dict.fromkeys(sorted(without_clutter), 0)
        assert rows[name, "cpu"]["wide"]["differing_values"] == dict.fromkeys(sorted(gpucheck.BATCH_ARRAYS), 0)
    assert rows["poison", "cpu"]["wide"]["poisoned_bytes"] > 0
    walks = rows["walks", "cpu"]
    assert walks["hit_pattern_agreement"] == 1.0 and walks["ray_agreement"] == 1.0 and walks["point_max_abs_m"] < 1e-4
    assert walks["hits_a"] == walks["hits_b"] > 0.2 * walks["rays"]
    for batch in (1, 8):
        s = rows[f"stream b={batch}", "cpu"]
        assert (s["batch"], s["timer"], s["lidar"]) == (batch, "perf_counter", "hdl32e")
        assert 1 <= s["repeats"] <= 3 and len(s["times_s"]) == s["repeats"]
        assert s["median_s"] == pytest.approx(float(np.median(s["times_s"])))
        assert s["pairs_per_s"] == pytest.approx(batch / s["median_s"])
        assert s["scans_per_s"] == pytest.approx(batch / s["stages"]["ray_cast"]["median_s"])
        assert s["rays_per_s"] == pytest.approx(s["scans_per_s"] * s["rays_per_scan"])
        assert set(s["stages_median_s"]) == {"terrain", "ray_cast", "maps"}
        assert "meets_target" not in s  # targets are for CUDA
    t = rows["train b=8", "cpu"]
    assert t["batch"] == 8 and t["model"]["name"] == RunConfig().model.name and t["model"]["ngf"] == RunConfig().model.ngf
    assert t["pairs_per_s"] == pytest.approx(8 / t["median_s"]) and 1 <= t["repeats"] <= 2
    for label in ("octave5", "wide"):
        c = rows["capture", "cpu"][label]
        assert c["cuda_graph"] is False and c["arrays"] > 10 and len(c["seeds"]) == 3 and set(c["differing_values"].values()) == {0}
    for batch in (1, 8):
        r = rows[f"stream b={batch}", "cpu"]["replayed"]
        assert r["cuda_graph"] is False and r["pairs_per_s"] == pytest.approx(batch / r["median_s"])
    split = rows["process_split", "cpu"]
    assert split["processes"] == 2 and split["heightfields"]["differing_values"] == 0 and "scan" not in split  # quick: terrains only


@pytest.mark.slow
def test_the_quick_run_prints_the_environment_and_the_table(quick):
    _, stdout, report = quick
    env = report["environment"]
    assert f"python {env['python']}" in stdout and f"torch {env['torch']}" in stdout and f"warp {env['warp']}" in stdout
    assert ("CUDA: driver" in stdout) if CUDA else (f"CUDA: none ({CUDA_REASON})" in stdout)
    for r in report["checks"]:
        line = table_line(stdout, r["name"], r["device"])
        assert f"  {r['status']}  " in line
        assert (r["detail"] if r["status"] == "PASS" else r["reason"]) in line
    c = report["counts"]
    assert f"{c['PASS']} PASS, 0 FAIL, {c['SKIP']} SKIP in " in stdout and stdout.rstrip().splitlines()[-1].startswith("report written to ")


# ------------------------------------------------------------------------------ failures
def test_a_check_that_finds_a_difference_fails_the_run(monkeypatch, tmp_path):
    """``generate_batch`` made non-deterministic (every second call moves one terrain vertex):
    the repeat check says which array differs, the table says FAIL, the exit code is 1."""
    calls = {"n": 0}
    real = gpucheck.generate_batch

    def flaky(*args, **kwargs):
        batch = real(*args, **kwargs)
        calls["n"] += 1
        if calls["n"] % 2 == 0:
            batch.heights[0, 0, 0] += 1.0
        return batch

    monkeypatch.setattr(gpucheck, "generate_batch", flaky)
    path = tmp_path / "r.json"
    code, stdout = run_cli("--quick", "--only", "repeat", "--json", str(path), "-q")
    assert code == 1
    report = json.loads(path.read_text())
    row = report["checks"][0]
    assert (row["name"], row["device"], row["status"]) == ("repeat", "cpu", "FAIL")
    assert row["reason"] == "octave5: heights differs in 1 values; wide: heights differs in 1 values"
    assert row["figures"]["wide"]["differing_values"]["heights"] == 1 and row["figures"]["wide"]["differing_values"]["points"] == 0
    assert report["ok"] is False and report["counts"]["FAIL"] == (2 if CUDA else 1)
    assert "  FAIL  " in table_line(stdout, "repeat", "cpu") and "octave5: heights differs in 1 values" in stdout
    assert "1 FAIL" in stdout or "2 FAIL" in stdout


def _switches_row(monkeypatch=None, doctor=None):
    ctx = gpucheck.Context(gpucheck.make_plan(quick=True), deadline=time.monotonic() + 300)
    if doctor is not None:
        monkeypatch.setattr(gpucheck, "scan_terrains", doctor)
    return gpucheck.check_switches(ctx, "cpu", batch=1)


def test_the_switches_row_compares_every_variant_with_the_default():
    out = _switches_row()
    assert out.failures == []
    casts = out.figures["ray_cast"]
    assert list(casts) == ["default", *gpucheck.COLUMN_SWITCHES]
    for name in gpucheck.COLUMN_SWITCHES:
        assert casts[name]["differing_values"] == {"points": 0}
        assert casts[name]["speedup"] == pytest.approx(casts["default"]["median_s"] / casts[name]["median_s"])
    terrain = out.figures["terrain"]
    assert terrain["other_path"] == "per-vertex wp.noise" and 0 < terrain["other"]["max_abs_m"] <= gpucheck.TERRAIN_ATOL_M
    assert out.detail.startswith("ray cast static_tile ") and "fBm via per-vertex wp.noise" in out.detail


def test_a_switch_that_changes_the_points_fails_its_row(monkeypatch):
    from warp_terrain.sim.switches import kernel_switches

    real = gpucheck.scan_terrains

    def off_when_deferred(heights, sim, seed, device):
        points, sensor_z = real(heights, sim, seed, device)
        if kernel_switches().deferred_writes:
            moved = wp.to_torch(points)
            moved[0, 0] = 99.0  # one ray's point, whatever it was
        return points, sensor_z

    out = _switches_row(monkeypatch, off_when_deferred)
    assert out.failures == ["deferred_writes: points differs in 3 values", "static_tile+deferred_writes: points differs in 3 values"]
    assert out.figures["ray_cast"]["static_tile"]["differing_values"] == {"points": 0}


def test_a_replay_that_differs_fails_the_capture_row(monkeypatch):
    real = gpucheck.BatchGraph.__call__

    def stale_on_replay(self, seed=0):
        first = not self.replays
        out = real(self, seed)
        if not first:
            out.target[0, 0, 0, 0] += 1.0
        return out

    monkeypatch.setattr(gpucheck.BatchGraph, "__call__", stale_on_replay)
    ctx = gpucheck.Context(gpucheck.make_plan(quick=True), deadline=time.monotonic() + 300)
    out = gpucheck.check_capture(ctx, "cpu")
    assert out.failures == ["octave5: target differs in 2 values", "wide: target differs in 2 values"]
    assert out.figures["octave5"]["differing_values"]["points"] == 0 and "differ" in out.detail


def test_kernel_times_sum_each_activity_over_its_launches(monkeypatch):
    from types import SimpleNamespace

    started = []
    monkeypatch.setattr(wp, "timing_begin", lambda cuda_filter: started.append(cuda_filter))
    monkeypatch.setattr(wp, "timing_end", lambda: [SimpleNamespace(name="cast_columns", elapsed=2.0), SimpleNamespace(name="memset", elapsed=0.5),
                                                   SimpleNamespace(name="cast_columns", elapsed=1.5)])
    calls = []
    times = gpucheck.kernel_times(lambda: calls.append(1), "cpu")
    assert calls == [1] and started == [wp.TIMING_KERNEL | wp.TIMING_MEMSET | wp.TIMING_MEMCPY]
    assert list(times.items()) == [("cast_columns", 3.5), ("memset", 0.5)]


def test_train_options_are_named():
    with pytest.raises(ValueError, match="train option 'fp8': choose from bf16_autocast, cudnn_benchmark"):
        with gpucheck.train_option("fp8"):
            pass


def test_a_check_that_raises_is_a_fail_with_its_error(monkeypatch, tmp_path):
    def broken(*args, **kwargs):
        raise RuntimeError("kernel launch failed")

    monkeypatch.setattr(gpucheck, "trace", broken)
    path = tmp_path / "r.json"
    code, stdout = run_cli("--only", "walks", "--json", str(path), "-q")
    assert code == 1
    row = json.loads(path.read_text())["checks"][0]
    assert (row["name"], row["status"], row["reason"]) == ("walks", "FAIL", "RuntimeError: kernel launch failed")
    assert row["figures"]["traceback"][-1] == "RuntimeError: kernel launch failed"
    assert "RuntimeError: kernel launch failed" in table_line(stdout, "walks", "cpu")


# ------------------------------------------------------------------------------ the comparisons the CUDA rows use
@pytest.fixture(scope="module")
def cpu_batch():
    return gpucheck.host_arrays(wt.generate_batch(2, tiny_sim(), seed=4, device="cpu"))


def doctored(ref: dict, **edits) -> dict:
    other = {k: v.copy() for k, v in ref.items()}
    for name, fn in edits.items():
        fn(other[name])
    return other


def test_identical_batches_compare_equal(cpu_batch):
    fig, bad = gpucheck.compare_batches(cpu_batch, doctored(cpu_batch))
    assert bad == []
    assert (fig["terrain_max_abs_m"], fig["point_max_abs_m"], fig["ray_agreement"], fig["mask_agreement"], fig["target_max_abs_m"]) == (0, 0, 1, 1, 0)
    assert fig["rays"] == cpu_batch["points"].shape[0] * cpu_batch["points"].shape[1] and fig["hits_a"] == fig["hits_b"] > 0
    assert gpucheck.bit_differences(cpu_batch, doctored(cpu_batch)) == dict.fromkeys(sorted(cpu_batch), 0)


def _first_hit(points: np.ndarray) -> tuple[int, int]:
    b, n = np.argwhere(np.isfinite(points).all(-1))[0]
    return int(b), int(n)


def test_a_point_off_by_more_than_a_millimetre_fails_rays_agreement(cpu_batch):
    """One ray in 5760 (1.7e-4) off by 2 mm is below 99.99 %; by 0.5 mm it is the same hit."""
    b, n = _first_hit(cpu_batch["points"])
    rays = cpu_batch["points"].shape[0] * cpu_batch["points"].shape[1]
    assert rays < 10_000

    def shift(d):
        def edit(p):
            p[b, n, 0] += d
        return edit

    fig, bad = gpucheck.compare_batches(cpu_batch, doctored(cpu_batch, points=shift(2e-3)))
    assert fig["ray_agreement"] == pytest.approx(1 - 1 / rays) and fig["point_max_abs_m"] == pytest.approx(2e-3, rel=1e-3)
    assert len(bad) == 1 and bad[0].startswith("points: ") and "of rays agree (< 99.99 %" in bad[0]
    fig, bad = gpucheck.compare_batches(cpu_batch, doctored(cpu_batch, points=shift(5e-4)))
    assert bad == [] and fig["ray_agreement"] == 1.0
    lost = doctored(cpu_batch, points=lambda p: p.__setitem__((b, n), np.nan))  # a hit on one side only
    fig, bad = gpucheck.compare_batches(cpu_batch, lost)
    assert fig["hit_pattern_agreement"] == pytest.approx(1 - 1 / rays) and len(bad) == 1


def test_terrain_masks_and_targets_have_their_tolerances(cpu_batch):
    fig, bad = gpucheck.compare_batches(cpu_batch, doctored(cpu_batch, heights=lambda h: h.__setitem__((0, 5, 5), h[0, 5, 5] + 2e-5)))
    assert fig["terrain_max_abs_m"] == pytest.approx(2e-5, rel=1e-2) and len(bad) == 1 and bad[0].startswith("terrain differs by 2e-05 m")
    fig, bad = gpucheck.compare_batches(cpu_batch, doctored(cpu_batch, heights=lambda h: h.__setitem__((0, 5, 5), h[0, 5, 5] + 5e-6)))
    assert bad == []
    cells = cpu_batch["mask"].size  # 2 x 41 x 41 = 3362: one flipped cell is 99.97 % (passes), ten are 99.70 % (fail)
    flip = lambda k: lambda m: m.reshape(-1).__setitem__(slice(0, k), 1.0 - m.reshape(-1)[:k])  # noqa: E731
    fig, bad = gpucheck.compare_batches(cpu_batch, doctored(cpu_batch, mask=flip(1)))
    assert fig["mask_agreement"] == pytest.approx(1 - 1 / cells) and bad == []
    fig, bad = gpucheck.compare_batches(cpu_batch, doctored(cpu_batch, mask=flip(10)))
    assert fig["mask_agreement"] == pytest.approx(1 - 10 / cells) and bad == ["masks agree on 99.703 % of cells (< 99.9 %)"]
    fig, bad = gpucheck.compare_batches(cpu_batch, doctored(cpu_batch, target=lambda t: t.__iadd__(2e-3)))
    assert fig["target_max_abs_m"] == pytest.approx(2e-3, rel=1e-3) and bad == ["target differs by 0.002 m (> 0.001)"]


def test_bit_differences_count_values_and_see_missing_arrays():
    a = {"x": np.array([0.0, 1.0, np.nan], np.float32), "y": np.zeros(2, np.float32)}
    b = {"x": np.array([-0.0, 1.0, np.nan], np.float32), "z": np.zeros(2, np.float32)}
    assert gpucheck.bit_differences(a, b) == {"x": 1, "y": -1, "z": -1}  # -0.0 differs from 0.0 in its sign bit


# ------------------------------------------------------------------------------ timing and the time limit
def test_timed_warms_up_then_times_the_repeats():
    calls = []
    out = gpucheck.timed(lambda: calls.append(1), "cpu", warmup=2, repeats=3, cap_s=60.0, deadline=float("inf"))
    assert len(calls) == 5 and (out["timer"], out["warmup"], out["repeats"], len(out["times_s"])) == ("perf_counter", 2, 3, 3)
    assert out["median_s"] == float(np.median(out["times_s"])) and out["wall_s"] >= sum(out["times_s"])
    with pytest.raises(gpucheck.TimeUp):
        gpucheck.timed(lambda: None, "cpu", warmup=1, repeats=3, cap_s=1.0, deadline=0.0)


def test_the_watchdog_reports_the_running_check_at_the_time_limit(monkeypatch):
    """A check still running at the hard limit is FAIL, those after it SKIP, and a
    ``time_limit`` row FAILs the run; ``on_timeout`` gets that report at the limit."""
    release = threading.Event()
    seen = []

    def ok(ctx):
        return gpucheck.Outcome({"x": 1}, "fine")

    def stuck(ctx):
        release.wait(30)
        return gpucheck.Outcome({}, "late")

    tasks = [gpucheck.Task("first", "compile", "cpu", ok), gpucheck.Task("stuck", "repeat", "cpu", stuck),
             gpucheck.Task("after", "walks", "cpu", ok)]
    monkeypatch.setattr(gpucheck, "plan_tasks", lambda *a: tasks)

    def on_timeout(report):
        seen.append(report)
        release.set()

    check = gpucheck.GpuCheck(quick=True, time_limit_s=1.5)
    check.collect_environment()
    final = check.run(on_timeout=on_timeout)
    assert len(seen) == 1
    snap = seen[0]
    assert [(r["name"], r["status"]) for r in snap["checks"]] == [("first", "PASS"), ("stuck", "FAIL"), ("after", "SKIP"), ("time_limit", "FAIL")]
    assert snap["checks"][1]["reason"].startswith("did not finish within the 1.5 s time limit (stopped after ")
    assert snap["checks"][2]["reason"] == "not run: the time limit was reached"
    assert snap["checks"][3]["reason"] == "the 1.5 s time limit was reached: 1 check(s) not run, the check running then was stopped"
    assert snap["timed_out"] is True and snap["complete"] is False and snap["ok"] is False
    assert snap["counts"] == {"PASS": 1, "FAIL": 2, "SKIP": 1}
    # the run went on once released (as it would if on_timeout did not end the process): still timed out
    assert [r["status"] for r in final["checks"]] == ["PASS", "PASS", "SKIP", "FAIL"] and final["timed_out"] is True


def test_the_command_stops_at_its_hard_time_limit(tmp_path):
    """The limit counts from the command's start: 0.5 s passes during its imports, so the
    watchdog stops it at once with the report written and exit code 1."""
    path = tmp_path / "r.json"
    proc = subprocess.run([sys.executable, "-m", "warp_terrain.cli", "gpu-check", "--quick", "--time-limit", "0.5", "--json", str(path), "-q"],
                          capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert proc.returncode == 1, proc.stderr[-2000:]
    report = json.loads(path.read_text())
    assert report["timed_out"] is True and report["ok"] is False and report["time_limit_s"] == 0.5
    last = report["checks"][-1]
    assert (last["name"], last["status"]) == ("time_limit", "FAIL") and last["reason"].startswith("the 0.5 s time limit was reached")
    assert "time_limit" in proc.stdout and "FAILED" in proc.stdout


# ------------------------------------------------------------------------------ arguments
@pytest.mark.parametrize("args, message", [
    (["--time-limit", "0"], "invalid time limit '0'"),
    (["--time-limit", "soon"], "invalid time limit 'soon'"),
    (["--only", "repeat,speed"], "unknown check 'speed': choose from compile,repeat,poison,walks,cuda_vs_cpu,capture,no_sync,stream,switches,train,process_split"),
    (["--json", "/nonexistent/folder/r.json"], "error: --json '/nonexistent/folder/r.json': the folder '/nonexistent/folder' does not exist"),
])
def test_bad_arguments_exit_2_before_any_check(args, message, capsys):
    code = main(["gpu-check", *args])
    err = capsys.readouterr().err
    assert code == 2 and message in err


def test_a_folder_as_json_output_is_refused(tmp_path, capsys):
    assert main(["gpu-check", "--json", str(tmp_path)]) == 2
    assert f"--json {str(tmp_path)!r}: is a folder; name a file" in capsys.readouterr().err


def test_the_command_and_the_library_agree_on_the_checks_and_kernel_modules():
    assert CLI_GROUPS == gpucheck.GROUPS
    assert sorted(gpucheck.KERNEL_MODULES) == KERNEL_FILES
    with pytest.raises(ValueError, match="unknown or no check names"):
        gpucheck.parse_groups("walks,nope")
    assert gpucheck.parse_groups("walks,repeat") == ("repeat", "walks")  # in run order
    with pytest.raises(ValueError, match="time_limit_s=0"):
        gpucheck.GpuCheck(time_limit_s=0)


def test_the_device_script_is_valid_bash():
    script = ROOT / "tools" / "gpu_check.sh"
    assert subprocess.run(["bash", "-n", str(script)], capture_output=True).returncode == 0
    assert "gpu-check --json \"$OUT/gpu_check.json\"" in script.read_text()


def test_gpu_check_is_a_registered_subcommand():
    from warp_terrain.cli import SUBCOMMANDS, build_parser
    from warp_terrain.cli.gpucheck import add_gpu_check, cmd_gpu_check

    assert add_gpu_check in SUBCOMMANDS and callable(cmd_gpu_check)
    assert "gpu-check" in build_parser().format_help()
