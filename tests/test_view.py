"""``warp-terrain view``: the scene's meshes as known answers (no browser), the viser server
in-process (the page over HTTP, the scene over its websocket), the command, and a headless
Chromium screenshot where Chromium is installed."""

from __future__ import annotations

import json
import os
import shutil
import signal
import struct
import subprocess
import sys
import tempfile
import time
import urllib.error
import urllib.request
from pathlib import Path

import matplotlib
import numpy as np
import pytest
import torch
from conftest import tiny_sim

from warp_terrain.cli import main
from warp_terrain.core.geometry import MapGeometry
from warp_terrain.inference.maps import write_map
from warp_terrain.plots.scene3d import (
    LAYERS,
    NAN_RGB,
    NODE_NAMES,
    PANEL_GAP,
    POINT_RGB,
    LabelNode,
    MeshNode,
    PointsNode,
    ViewSample,
    build_scene,
    colormap_rgb,
    load_map_file,
    mesh_glb,
    simulated_samples,
    srgb_to_linear,
    surface_faces,
    surface_mesh,
    tiles_mesh,
    vertex_normals,
)
from warp_terrain.sim import generate_batch

ROOT = Path(__file__).resolve().parents[1]


def _sample(S: int = 9, cell: float = 0.5, points: int = 10, sigma: bool = True) -> ViewSample:
    g = MapGeometry(S, cell)
    h = np.linspace(-1.0, 1.0, S * S, dtype=np.float32).reshape(S, S)
    mask = np.zeros((S, S), bool)
    mask[2:5, 3:6] = True
    rng = np.random.default_rng(0)
    return ViewSample(g, prediction=h, truth=h + 0.25, scan=np.where(mask, h, 0.0).astype(np.float32), mask=mask,
                      uncertainty=np.abs(h) if sigma else None, points=rng.uniform(-1, 1, (points, 3)).astype(np.float32),
                      title="test sample")


# ------------------------------------------------------------------------------ meshes
def test_surface_of_the_paper_map_sits_on_the_map_geometry():
    g = MapGeometry()  # 121 x 121 cells of 0.25 m
    S = g.size
    h = np.arange(S * S, dtype=np.float32).reshape(S, S) / 1000.0
    mesh = surface_mesh(h, g, colormap_rgb(h, 0.0, 1.0))
    assert mesh.vertices.shape == (S * S, 3) and mesh.vertices.dtype == np.float32
    assert mesh.faces.shape == (2 * (S - 1) ** 2, 3) == (28800, 3)
    assert mesh.colors.shape == (S * S, 3) and mesh.colors.dtype == np.uint8
    # vertex p*S + q at the centre of cell (p, q): (p - 60) * 0.25, (q - 60) * 0.25
    assert mesh.vertices[0].tolist() == [-15.0, -15.0, 0.0]
    assert mesh.vertices[120].tolist() == [-15.0, 15.0, np.float32(120 / 1000.0)]
    assert mesh.vertices[60 * S + 60].tolist() == [0.0, 0.0, np.float32((60 * S + 60) / 1000.0)]
    assert mesh.vertices[3 * S + 7].tolist() == [-14.25, -13.25, np.float32((3 * S + 7) / 1000.0)]
    c = g.centres().astype(np.float32)
    np.testing.assert_array_equal(mesh.vertices.reshape(S, S, 3)[..., 0], np.broadcast_to(c[:, None], (S, S)))
    np.testing.assert_array_equal(mesh.vertices.reshape(S, S, 3)[..., 1], np.broadcast_to(c[None, :], (S, S)))
    assert mesh.faces.max() == S * S - 1 and np.unique(mesh.faces).size == S * S


def test_surface_faces_follow_the_simulators_diagonal_counter_clockwise():
    faces = surface_faces(4)
    assert faces.shape == (18, 3) and faces.dtype == np.uint32
    # cell (0, 0): (0,0),(1,0),(1,1) then (0,0),(1,1),(0,1); cell (0, 1) next
    assert faces[:4].tolist() == [[0, 4, 5], [0, 5, 1], [1, 5, 6], [1, 6, 2]]
    mesh = surface_mesh(np.zeros((4, 4)), MapGeometry(4, 1.0), np.zeros((4, 4, 3), np.uint8))
    v = mesh.vertices[mesh.faces.astype(int)]
    normal_z = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])[:, 2]
    np.testing.assert_array_equal(normal_z, np.full(18, 1.0, np.float32))  # twice the area of half a 1 m cell, facing +z
    with pytest.raises(ValueError, match="at least 2 x 2"):
        surface_faces(1)


def test_colours_come_from_the_colormap_at_known_heights():
    g = MapGeometry(3, 1.0)
    h = np.array([[-2.0, 0.5, 3.0], [-5.0, 9.0, -2.0], [0.5, 3.0, 0.5]], np.float32)
    mesh = surface_mesh(h, g, colormap_rgb(h, -2.0, 3.0))
    rgb = mesh.colors.reshape(3, 3, 3)
    assert rgb[0, 0].tolist() == [68, 1, 84]  # viridis at 0: #440154
    assert rgb[0, 2].tolist() == [253, 231, 36]  # viridis at 1
    assert rgb[0, 1].tolist() == [32, 144, 140]  # halfway: viridis(0.5)
    assert rgb[1, 0].tolist() == [68, 1, 84] and rgb[1, 1].tolist() == [253, 231, 36]  # clipped below and above
    assert colormap_rgb(np.array([0.0, 0.5, 1.0, np.nan]), 0.0, 1.0, "magma").tolist() == [
        list(matplotlib.colormaps["magma"](0.0, bytes=True)[:3]), list(matplotlib.colormaps["magma"](0.5, bytes=True)[:3]),
        list(matplotlib.colormaps["magma"](1.0, bytes=True)[:3]), list(NAN_RGB)]
    assert colormap_rgb(np.array([4.0]), 4.0, 4.0).tolist() == [[68, 1, 84]]  # a flat map: one colour, no division by 0
    with pytest.raises(ValueError, match="not a matplotlib colormap"):
        colormap_rgb(h, 0.0, 1.0, "no-such-map")


def test_scan_tiles_are_one_square_per_observed_cell():
    g = MapGeometry(5, 0.5)
    values = np.arange(25, dtype=np.float32).reshape(5, 5)
    mask = np.zeros((5, 5), bool)
    mask[0, 0] = mask[2, 3] = mask[4, 1] = True
    mesh = tiles_mesh(values, mask, g, colormap_rgb(values, 0.0, 24.0))
    assert mesh.vertices.shape == (12, 3) and mesh.faces.shape == (6, 3)
    # cell (2, 3) (the second set cell): centre (0.0, 0.5), corners +-0.25, at its value 13
    assert mesh.vertices[4:8].tolist() == [[-0.25, 0.25, 13.0], [0.25, 0.25, 13.0], [0.25, 0.75, 13.0], [-0.25, 0.75, 13.0]]
    assert mesh.faces[2:4].tolist() == [[4, 5, 6], [4, 6, 7]]
    assert mesh.colors[4:8].tolist() == [colormap_rgb(13.0, 0.0, 24.0).tolist()] * 4
    assert tiles_mesh(values, np.zeros((5, 5), bool), g, np.zeros((5, 5, 3), np.uint8)).faces.shape == (0, 3)


def test_normals_of_a_plane_are_its_normal():
    g = MapGeometry(6, 0.5)
    x = g.centres()
    plane = np.broadcast_to(0.5 * x[:, None], (6, 6))  # z = 0.5 x
    n = vertex_normals(surface_mesh(plane, g, np.zeros((6, 6, 3), np.uint8)))
    np.testing.assert_allclose(n, np.broadcast_to(np.array([-0.5, 0.0, 1.0]) / np.sqrt(1.25), (36, 3)), atol=1e-6)


def _read_glb(data: bytes):
    magic, version, total = struct.unpack_from("<4sII", data, 0)
    assert (magic, version, total) == (b"glTF", 2, len(data))
    json_len, json_type = struct.unpack_from("<I4s", data, 12)
    assert json_type == b"JSON" and json_len % 4 == 0
    doc = json.loads(data[20 : 20 + json_len])
    bin_len, bin_type = struct.unpack_from("<I4s", data, 20 + json_len)
    assert bin_type == b"BIN\0" and 28 + json_len + bin_len == len(data)
    blob = data[28 + json_len :]

    def accessor(k):
        a = doc["accessors"][k]
        view = doc["bufferViews"][a["bufferView"]]
        dtype = {5126: np.float32, 5125: np.uint32}[a["componentType"]]
        width = {"VEC3": 3, "SCALAR": 1}[a["type"]]
        raw = np.frombuffer(blob, dtype, count=a["count"] * width, offset=view["byteOffset"])
        return raw.reshape(a["count"], width) if width > 1 else raw

    attributes = doc["meshes"][0]["primitives"][0]["attributes"]
    return doc, {name: accessor(k) for name, k in attributes.items()}, accessor(doc["meshes"][0]["primitives"][0]["indices"])


def test_glb_holds_the_mesh_exactly():
    g = MapGeometry(7, 0.25)
    h = np.linspace(-1, 2, 49, dtype=np.float32).reshape(7, 7)
    mesh = surface_mesh(h, g, colormap_rgb(h, -1.0, 2.0))
    doc, attrs, indices = _read_glb(mesh_glb(mesh))
    assert doc["asset"]["version"] == "2.0" and doc["materials"][0]["doubleSided"] is True
    np.testing.assert_array_equal(attrs["POSITION"], mesh.vertices)
    np.testing.assert_array_equal(indices.reshape(-1, 3), mesh.faces)
    np.testing.assert_array_equal(attrs["NORMAL"], vertex_normals(mesh))
    np.testing.assert_array_equal(attrs["COLOR_0"], srgb_to_linear(mesh.colors))  # glTF's colours are linear
    position = doc["accessors"][doc["meshes"][0]["primitives"][0]["attributes"]["POSITION"]]
    assert position["min"] == [-0.75, -0.75, -1.0] and position["max"] == [0.75, 0.75, 2.0]
    assert srgb_to_linear(np.array([0, 255, 188], np.uint8)).tolist() == pytest.approx([0.0, 1.0, 0.502886], abs=1e-6)


# ------------------------------------------------------------------------------ scene
def test_scene_has_three_panels_side_by_side_and_the_layers_nodes():
    sample = _sample()
    scene = build_scene(sample)
    assert set(scene.nodes) == set(NODE_NAMES)
    pitch = sample.geometry.extent * (1 + PANEL_GAP)  # 4.5 m maps, 0.45 m apart
    assert scene.nodes["/input/scan"].position == (-pitch, 0.0, 0.0)
    assert scene.nodes["/input/points"].position == (-pitch, 0.0, 0.0)
    assert scene.nodes["/prediction/surface"].position == (0.0, 0.0, 0.0)
    assert scene.nodes["/truth/surface"].position == (pitch, 0.0, 0.0)
    assert all(isinstance(scene.nodes[name], MeshNode) for name in ("/input/scan", "/prediction/surface", "/truth/surface"))
    assert isinstance(scene.nodes["/input/points"], PointsNode) and scene.nodes["/input/points"].color == POINT_RGB
    np.testing.assert_array_equal(scene.nodes["/input/points"].points, sample.points)
    assert all(isinstance(scene.nodes[f"/{p}/label"], LabelNode) for p in ("input", "prediction", "truth"))
    assert scene.nodes["/input/scan"].mesh.faces.shape == (2 * 9, 3)  # 9 observed cells
    assert sample.color_modes() == ("height", "uncertainty", "error") and sample.layers() == tuple(LAYERS)
    # one height scale: -1 .. 1.25 (the truth is raised by 0.25)
    truth = scene.nodes["/truth/surface"].mesh
    assert truth.colors[-1].tolist() == [253, 231, 36] and scene.nodes["/prediction/surface"].mesh.colors[0].tolist() == [68, 1, 84]
    assert "-1.00 m (dark) to 1.25 m" in scene.legend


@pytest.mark.parametrize("mode", ["uncertainty", "error"])
def test_uncertainty_and_error_colour_the_prediction_only(mode):
    sample = _sample()
    scene = build_scene(sample, mode)
    spread = np.abs(sample.prediction) if mode == "uncertainty" else np.full((9, 9), 0.25)
    expected = colormap_rgb(spread, 0.0, float(spread.max()), "magma").reshape(-1, 3)
    np.testing.assert_array_equal(scene.nodes["/prediction/surface"].mesh.colors, expected)
    np.testing.assert_array_equal(scene.nodes["/truth/surface"].mesh.colors, build_scene(sample).nodes["/truth/surface"].mesh.colors)
    assert "magma" in scene.legend


def test_scene_without_a_model_or_truth_has_only_its_panels():
    no_model = ViewSample(MapGeometry(5, 1.0), truth=np.zeros((5, 5)), scan=np.zeros((5, 5)), mask=np.ones((5, 5), bool))
    scene = build_scene(no_model)
    assert set(scene.nodes) == {"/truth/surface", "/truth/label", "/input/scan", "/input/label"}
    assert scene.nodes["/input/scan"].position == (-0.5 * 5 * 1.1, 0.0, 0.0) and scene.nodes["/truth/surface"].position == (2.75, 0.0, 0.0)
    assert no_model.color_modes() == ("height",) and no_model.layers() == ("truth", "scan")
    with pytest.raises(ValueError, match="offers height"):
        build_scene(no_model, "uncertainty")
    with pytest.raises(ValueError, match="needs a prediction, a truth or a scan"):
        ViewSample(MapGeometry(5, 1.0))
    with pytest.raises(ValueError, match=r"truth: shape \(4, 4\) is not the map's \(5, 5\)"):
        ViewSample(MapGeometry(5, 1.0), truth=np.zeros((4, 4)))


def test_a_reconstructed_map_file_reads_back_as_a_view(tmp_path):
    g = MapGeometry(11, 0.5)
    rng = np.random.default_rng(1)
    height = rng.normal(size=(11, 11)).astype(np.float32)
    mask = rng.random((11, 11)) < 0.3
    sigma = rng.random((11, 11)).astype(np.float32)
    path = write_map(tmp_path / "map.npz", {"height": height, "mask": mask.astype(np.float32), "uncertainty": sigma}, g)
    view = load_map_file(path)
    assert view.geometry == g and view.title == "map.npz"
    np.testing.assert_array_equal(view.prediction, height)
    np.testing.assert_array_equal(view.mask, mask)
    np.testing.assert_array_equal(view.uncertainty, sigma)
    np.testing.assert_array_equal(view.scan[mask], height[mask])
    assert view.truth is None and view.points is None and view.panels() == ("input", "prediction")
    scene = build_scene(view, "uncertainty")
    assert set(scene.nodes) == {"/prediction/surface", "/prediction/label", "/input/scan", "/input/label"}
    assert scene.nodes["/input/scan"].mesh.faces.shape == (2 * int(mask.sum()), 3)
    no_sigma = load_map_file(write_map(tmp_path / "plain.npz", {"height": height, "mask": mask.astype(np.float32)}, g))
    assert no_sigma.uncertainty is None and no_sigma.color_modes() == ("height",)


@pytest.mark.parametrize("name, arrays, match", [
    ("missing.npz", None, "no such file"),
    ("map.tif", None, r"view reads \.npz maps"),
    ("nokeys.npz", {"height": np.zeros((4, 4))}, "missing mask, map_cell"),
    ("flat.npz", {"height": np.zeros(16), "mask": np.zeros(16), "map_cell": np.float32(0.25)}, r"height has shape \(16,\)"),
    ("cell.npz", {"height": np.zeros((4, 4)), "mask": np.zeros((4, 4)), "map_cell": np.float32(-1)}, "not a positive cell size"),
    ("mask.npz", {"height": np.zeros((4, 4)), "mask": np.zeros((3, 3)), "map_cell": np.float32(1)}, r"mask has shape \(3, 3\)"),
    ("nan.npz", {"height": np.full((4, 4), np.nan), "mask": np.zeros((4, 4)), "map_cell": np.float32(1)}, "NaN or infinite"),
    ("junk.npz", b"not a zip", "not a readable .npz"),
    ("text.npz", {"height": np.zeros((4, 4)), "mask": np.zeros((4, 4)), "map_cell": np.array("x")}, "not a positive cell size"),
    ("words.npz", {"height": np.full((4, 4), "a"), "mask": np.zeros((4, 4)), "map_cell": np.float32(1)}, "height holds <U1, not numbers"),
])
def test_bad_map_files_are_named(tmp_path, name, arrays, match):
    path = tmp_path / name
    if isinstance(arrays, bytes):
        path.write_bytes(arrays)
    elif arrays is not None:
        np.savez(path, **arrays)
    with pytest.raises(ValueError, match=match):
        load_map_file(path)


def test_simulated_samples_are_the_batch_and_the_predictors_maps():
    sim = tiny_sim()

    def predictor(scan, mask):
        return scan * 0.5 - 1.0, torch.full_like(scan, 0.2)

    sim.data.augment = True  # the view turns it off (on a copy): the terrain in its own orientation
    views = simulated_samples(sim, seed=3, count=2, predictor=predictor, device="cpu")
    assert sim.data.augment is True
    sim.data.augment = False
    b = generate_batch(2, sim, seed=3, device="cpu")
    assert len(views) == 2
    for i, view in enumerate(views):
        mask = b.mask[i, 0].numpy() > 0.5
        assert view.geometry == MapGeometry(41, 0.25) and view.title == f"octave5, seed 3, sample {i}"
        np.testing.assert_array_equal(view.truth, b.target[i, 0].numpy())
        np.testing.assert_array_equal(view.mask, mask)
        np.testing.assert_array_equal(view.scan[mask], b.scan[i, 0].numpy()[mask])
        np.testing.assert_array_equal(view.prediction, b.scan[i, 0].numpy() * 0.5 - 1.0)
        np.testing.assert_array_equal(view.uncertainty, np.full((41, 41), 0.2, np.float32))
        pts = b.points[i].numpy()
        np.testing.assert_array_equal(view.points, pts[np.isfinite(pts).all(axis=1)])
        assert 0 < len(view.points) < len(pts)
    plain = simulated_samples(sim, seed=3, count=1, device="cpu")[0]
    assert plain.prediction is None and plain.panels() == ("input", "truth")
    with pytest.raises(ValueError, match="count=0"):
        simulated_samples(sim, count=0)


# ------------------------------------------------------------------------------ the server
def _viser():
    return pytest.importorskip("viser", reason="viser is not installed: pip install 'warp-terrain[view]'")


def _scene_messages(url: str, until=lambda msgs: any(m["type"] == "ReplayDoneMessage" for m in msgs), seconds: float = 20.0):
    """The messages a browser gets from the viewer's websocket (viser's wire format: zstd msgpack)."""
    viser = _viser()
    import msgspec
    import zstandard
    from websockets.sync.client import connect

    messages = []
    deadline = time.monotonic() + seconds
    with connect(url.replace("http://", "ws://"), subprotocols=[f"viser-v{viser.__version__}"], max_size=None) as ws:
        while not until(messages):
            frame = ws.recv(timeout=max(0.1, deadline - time.monotonic()))
            inner_len, packed_len = struct.unpack_from("<QQ", frame, 0)
            inner = zstandard.ZstdDecompressor().decompress(frame[16 : 16 + packed_len], max_output_size=inner_len)
            messages.extend(msgspec.msgpack.decode(inner)["messages"])
    return messages


def _scene_state(messages) -> dict:
    """name -> (type, visible) of the scene nodes after ``messages``."""
    nodes = {}
    for m in messages:
        name = m.get("name")
        if m["type"] == "RemoveSceneNodeMessage":
            nodes.pop(name, None)
        elif m["type"] in ("GlbMessage", "PointCloudMessage", "LabelMessage"):
            nodes[name] = [m["type"], True]
        elif m["type"] == "SetSceneNodeVisibilityMessage" and name in nodes:
            nodes[name][1] = m["visible"]
    return {k: tuple(v) for k, v in nodes.items()}


EXPECTED_NODES = {
    "/truth/surface": "GlbMessage", "/prediction/surface": "GlbMessage", "/input/scan": "GlbMessage",
    "/input/points": "PointCloudMessage", "/truth/label": "LabelMessage", "/prediction/label": "LabelMessage", "/input/label": "LabelMessage",
}


def test_viewer_serves_the_page_and_the_scene_on_a_free_port():
    _viser()
    from warp_terrain.plots.viewer import start_viewer

    samples = [_sample(points=10), _sample(points=25, sigma=False)]
    viewer = start_viewer(samples, host="127.0.0.1", port=0, title="test view")
    try:
        assert viewer.port > 0 and viewer.url == f"http://127.0.0.1:{viewer.port}"
        with urllib.request.urlopen(viewer.url, timeout=10) as response:
            page = response.read().decode()
        assert response.status == 200 and "<title>Viser</title>" in page and '<div id="root">' in page
        assert set(viewer.nodes) == set(EXPECTED_NODES)

        messages = _scene_messages(viewer.url)
        state = _scene_state(messages)
        assert {name: kind for name, (kind, _visible) in state.items()} == EXPECTED_NODES
        assert all(visible for _kind, visible in state.values())
        glbs = {m["name"]: m for m in messages if m["type"] == "GlbMessage"}
        assert set(glbs) == {"/truth/surface", "/prediction/surface", "/input/scan"}
        gui = {m["props"]["label"]: m for m in messages if m["type"].startswith("Gui") and "label" in m.get("props", {})}
        assert {"sample", "colour by", "ground truth", "prediction", "LIDAR points", "scan"} <= set(gui)
        assert (gui["sample"]["type"], gui["sample"]["props"]["min"], gui["sample"]["props"]["max"]) == ("GuiSliderMessage", 0, 1)
        assert gui["colour by"]["type"] == "GuiDropdownMessage" and list(gui["colour by"]["props"]["options"]) == ["height", "uncertainty", "error"]
        assert gui["scan"]["type"] == "GuiCheckboxMessage" and gui["scan"]["value"] is True

        viewer.set_layer("truth", False)  # what the "ground truth" checkbox does
        viewer.set_color_by("uncertainty")
        state = _scene_state(_scene_messages(viewer.url))
        assert state["/truth/surface"] == ("GlbMessage", False) and state["/truth/label"] == ("LabelMessage", False)
        assert state["/prediction/surface"] == ("GlbMessage", True)
        viewer.show(1)  # the slider: sample 1 has no sigma, so the colouring falls back to height
        assert viewer.color_by == "height" and viewer.gui_color.value == "height"
        assert len(viewer.nodes["/input/points"].points) == 25
        with pytest.raises(ValueError, match="offers height, error"):
            viewer.set_color_by("uncertainty")
        viewer.gui_color.value = "uncertainty"  # picked in the page (sample 0 has it): the dropdown is put back
        viewer._on_color("uncertainty")
        assert viewer.color_by == "height" and viewer.gui_color.value == "height"
        viewer._on_color("error")
        assert viewer.color_by == "error" and viewer.gui_color.value == "error"
        with pytest.raises(ValueError, match=r"index=2: must be an integer in \[0, 1\]"):
            viewer.show(2)
    finally:
        url = viewer.url
        viewer.stop()
    with pytest.raises(urllib.error.URLError):  # stopped: nothing listens there any more
        urllib.request.urlopen(url, timeout=2)


def test_a_busy_port_moves_to_the_next_free_one():
    _viser()
    import socket

    from warp_terrain.plots.viewer import start_viewer

    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        taken = busy.getsockname()[1]
        viewer = start_viewer([_sample()], port=taken)
        try:
            assert viewer.port > taken
        finally:
            viewer.stop()


def test_viewer_refuses_bad_hosts_and_ports_before_starting():
    _viser()
    from warp_terrain.plots.viewer import start_viewer

    with pytest.raises(ValueError, match=r"port=70000: must be an integer in \[0, 65535\]"):
        start_viewer([_sample()], port=70000)
    with pytest.raises(ValueError, match="host='192.0.2.1': cannot listen there"):
        start_viewer([_sample()], host="192.0.2.1", port=0)  # TEST-NET-1: never this machine's
    with pytest.raises(ValueError, match="expected one or more ViewSample"):
        start_viewer([], port=0)


# ------------------------------------------------------------------------------ the command
def test_view_is_a_subcommand(capsys):
    from warp_terrain.cli import SUBCOMMANDS, build_parser
    from warp_terrain.cli.view import add_view, cmd_view

    assert add_view in SUBCOMMANDS and callable(cmd_view)
    assert "view" in build_parser().format_help()
    assert main(["view", "--help"]) == 0
    assert "--pretrained" in capsys.readouterr().out


def test_cli_without_viser_says_how_to_install_it(capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "viser", None)  # import viser -> ImportError
    assert main(["view", "--port", "0"]) == 2
    assert capsys.readouterr().err == "error: warp-terrain view needs viser: pip install 'warp-terrain[view]' (viser)\n"


def test_cli_refuses_contradictions_before_work(tmp_path, capsys):
    _viser()
    path = write_map(tmp_path / "m.npz", {"height": np.zeros((4, 4)), "mask": np.ones((4, 4))}, MapGeometry(4, 1.0))
    cases = [
        ([str(path), "--seed", "2", "--pretrained"], "--seed, --pretrained: the simulator's options"),
        (["--checkpoint", "x.pt", "--pretrained"], "name two models: give one"),
        ([str(tmp_path / "none.npz")], "no such file"),
        (["--host", "192.0.2.1"], "cannot listen there"),
    ]
    for extra, match in cases:
        assert main(["view", *extra, "--port", "0"]) == 2
        assert match in capsys.readouterr().err
    assert main(["view", "--port", "-1"]) == 2
    assert "invalid port '-1'" in capsys.readouterr().err


def test_cli_view_prints_its_url_serves_until_ctrl_c(tmp_path):
    _viser()
    g = MapGeometry(21, 0.5)
    height = np.fromfunction(lambda p, q: np.sin(p / 3.0) + 0.1 * q, (21, 21)).astype(np.float32)
    path = write_map(tmp_path / "scan.npz", {"height": height, "mask": (height > 0.5).astype(np.float32),
                                             "uncertainty": np.full((21, 21), 0.1, np.float32)}, g)
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    # Ctrl-C as a terminal delivers it: the suite may itself run as a background job (`make test &`,
    # nohup, CI runners), whose children inherit SIGINT ignored, and Python then never raises
    # KeyboardInterrupt; the viewer is started with SIGINT at its default, as from a shell prompt
    proc = subprocess.Popen([sys.executable, "-m", "warp_terrain.cli", "view", str(path), "--port", "0"], cwd=tmp_path,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        line = proc.stdout.readline()
        assert line.startswith("view: listening on http://127.0.0.1:") and line.endswith("; Ctrl-C to stop\n"), line
        url = line.split()[3].rstrip(";")
        with urllib.request.urlopen(url, timeout=10) as response:
            assert "<title>Viser</title>" in response.read().decode()
        state = _scene_state(_scene_messages(url))
        assert state == {"/prediction/surface": ("GlbMessage", True), "/prediction/label": ("LabelMessage", True),
                         "/input/scan": ("GlbMessage", True), "/input/label": ("LabelMessage", True)}
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=60)
        assert proc.returncode == 0, err
        assert out == ""  # one line only: viser's own banner and goodbye stay off stdout
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()


# ------------------------------------------------------------------------------ a real browser
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser") or ("/usr/bin/chromium" if Path("/usr/bin/chromium").exists() else None)


@pytest.mark.skipif(CHROMIUM is None, reason="no Chromium (Debian's chromium package: /usr/bin/chromium) for the screenshot")
def test_headless_chromium_loads_the_page_and_saves_a_screenshot(tmp_path):
    _viser()
    from warp_terrain.plots.viewer import start_viewer

    viewer = start_viewer([_sample(S=41, cell=0.25, points=200)], port=0)
    connected = []
    viewer.server.on_client_connect(connected.append)
    shot = tmp_path / "view.png"
    try:
        with tempfile.TemporaryDirectory() as profile:
            cmd = [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--enable-unsafe-swiftshader", "--disable-quic",
                   "--no-first-run", "--disable-background-networking", "--disable-component-update", "--disable-sync",
                   f"--user-data-dir={profile}", "--window-size=1280,800", "--virtual-time-budget=15000", "--hide-scrollbars",
                   f"--screenshot={shot}", viewer.url]
            done = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
        assert done.returncode == 0, done.stderr[-2000:]
        assert connected, "the page never opened the viewer's websocket"
    finally:
        viewer.stop()
    data = shot.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    width, height = struct.unpack(">II", data[16:24])
    assert (width, height) == (1280, 800)
    keep = os.environ.get("WARP_TERRAIN_VIEW_SCREENSHOT")
    if keep:
        shutil.copyfile(shot, keep)
