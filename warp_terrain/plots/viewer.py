"""``warp-terrain view``: the scene of :mod:`.scene3d` served as an interactive 3-D page (viser).

:func:`start_viewer` starts a viser server in a background thread and returns a
:class:`Viewer`: its ``url``, ``nodes`` (scene name -> viser handle, the nodes shown now) and
methods that do what the GUI controls do (``show`` a sample, ``set_color_by``, ``set_layer``).
viser is optional (the ``[view]`` extra) and imported only here, when a viewer starts.
"""

from __future__ import annotations

import contextlib
import io
import socket
import threading
from collections.abc import Sequence

from .scene3d import LAYERS, LabelNode, MeshNode, PointsNode, ViewSample, build_scene, mesh_glb

VIEW_INSTALL = "pip install 'warp-terrain[view]' (viser)"
#: GUI names of the layer toggles
LAYER_LABELS = {"truth": "ground truth", "prediction": "prediction", "points": "LIDAR points", "scan": "scan"}


def need_viser():
    """The viser module, or ValueError saying how to install it."""
    try:
        import viser
    except ImportError:
        raise ValueError(f"warp-terrain view needs viser: {VIEW_INSTALL}") from None
    return viser


def check_port(port) -> int:
    if isinstance(port, bool) or not isinstance(port, int) or not 0 <= port <= 65535:
        raise ValueError(f"port={port!r}: must be an integer in [0, 65535] (0: any free port)")
    return port


def check_host(host) -> str:
    """``host`` if this machine can listen on it (viser would retry a host it cannot bind forever)."""
    if not isinstance(host, str) or not host:
        raise ValueError(f"host={host!r}: must be a host name or address")
    try:
        family, kind, proto, _, address = socket.getaddrinfo(host, 0, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)[0]
        with socket.socket(family, kind, proto) as probe:
            probe.bind(address)
    except OSError as err:
        raise ValueError(f"host={host!r}: cannot listen there ({err.strerror or err})") from None
    return host


def url_of(host: str, port: int) -> str:
    """``http://HOST:PORT`` (an IPv6 host in brackets)."""
    return f"http://[{host}]:{port}" if ":" in host else f"http://{host}:{port}"


class Viewer:
    """A running viewer of ``samples`` (see :func:`start_viewer`); ``stop()`` ends it."""

    def __init__(self, server, samples: Sequence[ViewSample], title: str):
        self.server = server
        self.samples = list(samples)
        self.title = title
        self.index = 0
        self.color_by = "height"
        self.visible = {layer: True for layer in LAYERS}
        self.nodes: dict = {}
        self.scene = None
        self._lock = threading.RLock()
        self._build_gui()
        self.show(0)

    @property
    def host(self) -> str:
        return self.server.get_host()

    @property
    def port(self) -> int:
        return int(self.server.get_port())

    @property
    def url(self) -> str:
        return url_of(self.host, self.port)

    # -------------------------------------------------------------------------- GUI
    def _build_gui(self) -> None:
        gui = self.server.gui
        layers = [layer for layer in LAYERS if any(layer in s.layers() for s in self.samples)]
        modes = [mode for mode in ("height", "uncertainty", "error") if any(mode in s.color_modes() for s in self.samples)]
        self.gui_title = gui.add_markdown(f"**{self.title}**")
        self.gui_sample = None
        if len(self.samples) > 1:
            self.gui_sample = gui.add_slider("sample", min=0, max=len(self.samples) - 1, step=1, initial_value=0)
            self.gui_sample.on_update(lambda _event: self.show(int(self.gui_sample.value)))
        self.gui_color = gui.add_dropdown("colour by", modes, initial_value="height",
                                          hint="height for every surface; uncertainty (sigma) or error colours the prediction")
        self.gui_color.on_update(lambda _event: self._on_color(self.gui_color.value))
        self.gui_layers = {}
        with gui.add_folder("layers"):
            for layer in layers:
                box = gui.add_checkbox(LAYER_LABELS[layer], initial_value=True)
                box.on_update(lambda _event, layer=layer, box=box: self.set_layer(layer, box.value))
                self.gui_layers[layer] = box
        self.gui_legend = gui.add_markdown("")

    # -------------------------------------------------------------------------- scene
    def show(self, index: int) -> None:
        """Show sample ``index`` (replacing the scene's nodes), keeping the colouring if it has it."""
        if isinstance(index, bool) or not isinstance(index, int) or not 0 <= index < len(self.samples):
            raise ValueError(f"index={index!r}: must be an integer in [0, {len(self.samples) - 1}]")
        with self._lock:
            self.index = index
            sample = self.samples[index]
            if self.color_by not in sample.color_modes():
                self.color_by = "height"
            self._redraw()

    def set_color_by(self, mode: str) -> None:
        """Colour the surfaces by ``mode`` (one of the sample's ``color_modes()``)."""
        with self._lock:
            sample = self.samples[self.index]
            if mode not in sample.color_modes():
                raise ValueError(f"color_by={mode!r}: sample {self.index} offers {', '.join(sample.color_modes())}")
            self.color_by = mode
            self._redraw()

    def _on_color(self, mode: str) -> None:
        """The dropdown: a colouring this sample lacks (no sigma, no truth) puts the dropdown back."""
        with self._lock:
            if mode in self.samples[self.index].color_modes():
                self.set_color_by(mode)
            elif self.gui_color.value != self.color_by:
                self.gui_color.value = self.color_by

    def set_layer(self, layer: str, visible: bool) -> None:
        """Show or hide one of ``LAYERS`` (and a panel's label with its last layer)."""
        if layer not in LAYERS:
            raise ValueError(f"layer={layer!r}: one of {', '.join(LAYERS)}")
        with self._lock:
            self.visible[layer] = bool(visible)
            self._apply_visibility()

    def node_visible(self, name: str) -> bool:
        """Whether scene node ``name`` is shown now under the layer toggles."""
        for layer, names in LAYERS.items():
            if name in names:
                return self.visible[layer]
        panel = name.split("/")[1]  # a label: shown while any node of its panel is
        return any(self.node_visible(other) for other in self.nodes if other.startswith(f"/{panel}/") and other != name)

    def _apply_visibility(self) -> None:
        for name, handle in self.nodes.items():
            handle.visible = self.node_visible(name)

    def _redraw(self) -> None:
        sample = self.samples[self.index]
        scene = build_scene(sample, self.color_by)
        for handle in self.nodes.values():
            handle.remove()
        self.nodes = {}
        add = self.server.scene
        for name, node in scene.nodes.items():
            if isinstance(node, MeshNode):
                self.nodes[name] = add.add_glb(name, mesh_glb(node.mesh), position=node.position)
            elif isinstance(node, PointsNode):
                self.nodes[name] = add.add_point_cloud(name, node.points, node.color, point_size=node.size,
                                                       precision="float32", point_shape="circle", position=node.position)
            elif isinstance(node, LabelNode):
                self.nodes[name] = add.add_label(name, node.text, position=node.position, anchor="bottom-center")
        self.scene = scene
        self._apply_visibility()
        if self.gui_color.value != self.color_by:
            self.gui_color.value = self.color_by
        self.gui_title.content = f"**{self.title}**  \n{sample.title}"
        self.gui_legend.content = scene.legend
        if self.index == 0 and not getattr(self, "_camera_set", False):
            self.server.initial_camera.position = scene.eye
            self.server.initial_camera.look_at = scene.target
            self._camera_set = True

    def stop(self) -> None:
        """Stop the server (idempotent)."""
        with self._lock:
            if self.server is not None:
                with contextlib.redirect_stdout(io.StringIO()):  # viser's "Server stopped"
                    self.server.stop()
                self.server = None


def start_viewer(samples: Sequence[ViewSample], host: str = "127.0.0.1", port: int = 8080,
                 title: str = "warp-terrain view") -> Viewer:
    """Serve ``samples`` (from :func:`.scene3d.simulated_samples` or :func:`.scene3d.load_map_file`)
    on ``host:port`` (``port=0``: a free port the system picks; a busy port moves to the next free
    one, as viser does: ``Viewer.port`` says which) and return the running :class:`Viewer`."""
    samples = list(samples)
    if not samples or not all(isinstance(s, ViewSample) for s in samples):
        raise ValueError("samples: expected one or more ViewSample")
    host, port = check_host(host), check_port(port)
    viser = need_viser()
    with contextlib.redirect_stdout(io.StringIO()):  # viser prints a box of URLs; the caller prints one line
        server = viser.ViserServer(host=host, port=port, label="warp-terrain", verbose=False)
    server.scene.set_up_direction("+z")
    try:
        return Viewer(server, samples, title)
    except BaseException:
        server.stop()
        raise
