"""hevr.Viewer driven headlessly: each widget change gives the expected render call, re-colouring
happens on the client from the last decrypted frame (no render call, no map task), and every
frame matches render_plain within error_bound."""

from __future__ import annotations

import html
import io
import time

import numpy as np
import pytest
from PIL import Image

import hevr
from hevr.viewer import Viewer

pytest.importorskip("ipywidgets")  # the notebook extra; installed with the test extra


@pytest.fixture(scope="module")
def scene(tmp_path_factory, keypair256):
    pub, priv = keypair256
    vol = hevr.phantom(8)
    path = tmp_path_factory.mktemp("viewer") / "v.zarr"
    ev = hevr.encrypt_volume(vol, path, priv, brick=4, vector_dims=3, progress=False)
    return ev, priv, vol


@pytest.fixture
def viewer(scene):
    hevr.clear_cache()
    ev, priv, vol = scene
    return Viewer(ev, priv, volume=vol, width=10, height=8, mode="tf")


def _frame_matches(v: Viewer) -> None:
    """The frame on show decrypts to render_plain within error_bound, pixel by pixel."""
    last = v.history[-1]
    assert last["error"] is not None and last["error"] <= last["bound"]
    cam, kw = v.camera(), v.request()
    img = hevr.render(v.ev, cam, progress=False, **kw)  # cached: no map work
    arr = img.decrypt(v._key)
    ref = hevr.render_plain(v.volume, cam, value_range=v.ev.value_range, vector_dims=v.ev.vector_dims, **kw)
    assert (np.abs(arr - ref) <= hevr.error_bound(v.ev, cam, **kw)).all()
    assert bytes(v.image.value[:8]) == b"\x89PNG\r\n\x1a\n"


def test_first_frame_runs_the_map_step(viewer):
    first = viewer.history[-1]
    assert first["map_tasks"] > 0 and first["reused_ray_sums"] is False
    assert first["request"]["nodes"] == [(0.279, "#0000ff"), (0.797, "#ff0000")]
    _frame_matches(viewer)
    assert "map tasks" in viewer.status.value


def test_colour_change_alone_recolours_on_the_client(viewer):
    before = len(viewer.history)
    viewer.node_rows[0][1].value = "#00ff00"
    assert len(viewer.history) == before + 1
    last = viewer.history[-1]
    assert last["map_tasks"] == 0 and last["reused_ray_sums"] is True and last["client_recolour"] is True
    assert last["request"]["nodes"][0] == (0.279, "#00ff00")
    _frame_matches(viewer)
    assert "re-coloured on the client in" in viewer.status.value and "no server" in viewer.status.value


def test_a_tf_change_makes_no_render_call(viewer, monkeypatch):
    """After a render, TF and density edits re-colour the kept frame in the notebook: neither
    render_frame nor the render underneath is called; a camera move renders again."""
    import hevr.rendering.encrypted as encrypted
    import hevr.rendering.pipeline.stream as stream
    import hevr.rendering.slices as slices
    import hevr.viewer.widget as viewer_module

    calls = []

    def counting(fn, name):
        def wrapper(*a, **kw):
            calls.append(name)
            return fn(*a, **kw)

        return wrapper

    monkeypatch.setattr(viewer_module, "render_frame", counting(viewer_module.render_frame, "render_frame"))
    monkeypatch.setattr(stream, "render_view", counting(stream.render_view, "render_view"))
    monkeypatch.setattr(encrypted, "render_view", counting(encrypted.render_view, "render_view"))  # hevr.render's
    monkeypatch.setattr(slices, "render_view", counting(slices.render_view, "render_view"))
    first = viewer.history[-1]
    assert first["client_recolour"] is False and "request → decrypted frame" in viewer.status.value
    viewer.node_rows[1][1].value = "#ffff00"
    viewer.node_rows[0][0].value = 0.35
    viewer.add_node(0.6, "white")
    viewer.mode.value = "emphasize"
    viewer.density.value = 0.4
    assert calls == []
    assert all(e["client_recolour"] and e["map_tasks"] == 0 for e in viewer.history[-5:])
    cam, kw = viewer.camera(), viewer.request()
    shown = viewer.frame.recolour(kw["mode"], kw.get("density"), kw.get("nodes"))
    ref = hevr.render_plain(
        viewer.volume, cam, value_range=viewer.ev.value_range, vector_dims=viewer.ev.vector_dims, **kw
    )
    assert (np.abs(shown - ref) <= hevr.error_bound(viewer.ev, cam, **kw)).all()
    viewer.mode.value = "tf"
    assert calls == [] and viewer.history[-1]["request"]["nodes"][0] == (0.35, "#0000ff")
    last = viewer.history[-1]
    assert last["error"] is not None and last["error"] <= last["bound"]
    viewer.azimuth.value = 60.0  # a new camera: one render
    assert calls[:1] == ["render_frame"] and viewer.history[-1]["client_recolour"] is False


def test_add_and_remove_nodes(viewer):
    viewer.add_node(0.5, "yellow")
    assert len(viewer.nodes()) == 3 and viewer.history[-1]["map_tasks"] == 0
    assert viewer.nodes()[2] == (0.5, "#ffff00")
    viewer.node_rows[2][0].value = 0.6  # moving a node's density re-colours too
    assert viewer.history[-1]["map_tasks"] == 0 and viewer.history[-1]["request"]["nodes"][2][0] == 0.6
    _frame_matches(viewer)
    viewer.node_rows[0][2].click()  # the remove button of the first node
    assert [d for d, _ in viewer.nodes()] == [0.797, 0.6] and viewer.history[-1]["map_tasks"] == 0
    viewer.remove_node(0)
    n = len(viewer.history)
    viewer.remove_node(0)  # the last node stays
    assert len(viewer.nodes()) == 1 and len(viewer.history) == n and "at least one node" in viewer.status.value


def test_duplicate_density_is_reported_not_raised(viewer):
    shown = bytes(viewer.image.value)
    viewer.add_node(0.279, "white")  # the first node's density
    assert "distinct densities" in viewer.history[-1]["error_message"]
    assert "distinct densities" in viewer.status.value and bytes(viewer.image.value) == shown


def test_camera_sampling_and_mode_changes(viewer):
    viewer.azimuth.value = 75.0
    assert viewer.history[-1]["map_tasks"] > 0  # a new view needs the map step
    assert (
        viewer.history[-1]["camera"]
        == hevr.Camera.orbit(viewer.ev, azimuth=75, elevation=20, width=10, height=8).to_dict()
    )
    viewer.mode.value = "emphasize"  # same camera, same (vector) channel: re-coloured
    assert viewer.history[-1]["map_tasks"] == 0 and viewer.history[-1]["request"]["density"] == 0.653
    assert viewer.density.layout.display is None and viewer.tf_box.layout.display == "none"
    viewer.density.value = 0.331
    assert viewer.history[-1]["map_tasks"] == 0
    _frame_matches(viewer)
    viewer.mode.value = "xray"  # the scalar channel: another map step
    assert viewer.history[-1]["map_tasks"] > 0
    viewer.sampling.value = "trilinear"
    assert viewer.history[-1]["map_tasks"] > 0 and viewer.history[-1]["request"]["sampling"] == "trilinear"
    _frame_matches(viewer)


def test_hold_renders_once(viewer):
    n = len(viewer.history)
    with viewer.hold():
        viewer.azimuth.value = -40.0
        viewer.elevation.value = 10.0
        viewer.view_angle.value = 45.0
    assert len(viewer.history) == n + 1
    assert viewer.history[-1]["camera"]["view_angle"] == 45.0


def test_on_a_cluster_the_sums_stay_there(scene, cluster):
    hevr.clear_cache()
    ev, priv, vol = scene
    v = Viewer(ev, priv, volume=vol, width=10, height=8, mode="emphasize", client=cluster)
    assert v.history[-1]["map_tasks"] > 0
    v.density.value = 0.9
    assert v.history[-1]["map_tasks"] == 0 and v.history[-1]["reused_ray_sums"] is True
    _frame_matches(v)


def test_bad_input(scene, keypair512, tmp_path):
    ev, priv, vol = scene
    with pytest.raises(hevr.ParameterError, match="private_key: expected the key of this volume"):
        Viewer(ev, keypair512[1], show=False)
    with pytest.raises(hevr.ParameterError, match="private_key: expected a hevr.PrivateKey"):
        Viewer(ev, priv.public_key, show=False)
    with pytest.raises(hevr.ParameterError, match="volume: expected the plaintext of shape"):
        Viewer(ev, priv, volume=vol[:4], show=False)
    with pytest.raises(hevr.ParameterError, match="ev: expected an EncryptedVolume"):
        Viewer(str(ev.path), priv, show=False)
    scalar = hevr.encrypt_volume(vol, tmp_path / "s.zarr", priv, brick=4, progress=False)
    with pytest.raises(hevr.ParameterError, match=r"mode: expected one of \['xray'\]"):
        Viewer(scalar, priv, mode="tf", show=False)
    with pytest.raises(hevr.ParameterError, match="width"):
        Viewer(ev, priv, width=0, show=False)


def test_hidden_widgets_render_nothing_and_bad_indices_are_named(viewer):
    viewer.mode.value = "xray"
    n = len(viewer.history)
    viewer.density.value = 0.9  # hidden in X-ray mode
    viewer.node_rows[0][1].value = "#123456"  # so is the TF editor
    viewer.add_node(0.4, "white")
    assert len(viewer.history) == n
    viewer.mode.value = "tf"  # the edits apply when the editor shows again
    assert viewer.history[-1]["request"]["nodes"][0][1] == "#123456" and len(viewer.nodes()) == 3
    with pytest.raises(hevr.ParameterError, match=r"index: expected a node index in \[0, 3\)"):
        viewer.remove_node(3)
    viewer.add_node(float("nan"), "red")
    assert viewer.history[-1]["error_message"].startswith("nodes[3] density: expected a normalised density")
    assert viewer.status.value.endswith(html.escape(viewer.history[-1]["error_message"]) + "</span>")


def test_progressive_viewing_on_a_pyramid(scene, tmp_path):
    """A store with pyramid levels: a slider move shows a coarse frame (level 1 here), the full
    frame follows on settle() or after `settle` seconds of stillness."""
    ev, priv, vol = scene
    path = tmp_path / "p.zarr"
    pev = hevr.encrypt_volume(vol, path, priv, brick=4, vector_dims=3, progress=False)
    pev = hevr.build_pyramid(pev, 1, progress=False)
    hevr.clear_cache()
    v = Viewer(pev, priv, volume=vol, width=10, height=8, mode="emphasize", settle=None)
    assert v.preview == 1 and v.azimuth.continuous_update is True and v.history[-1]["level"] == 0
    v.azimuth.value = 50.0
    last = v.history[-1]
    assert last["level"] == 1 and last["map_tasks"] >= 1 and last["error"] <= last["bound"]
    assert "preview at pyramid level 1" in v.status.value
    full = v.settle()
    assert last["camera"]["width"] == 5 and last["camera"]["height"] == 4  # half the pixels per axis
    assert full["level"] == 0 and full["camera"] == {**last["camera"], "width": 10, "height": 8}
    assert full["error"] <= full["bound"]
    assert Image.open(io.BytesIO(bytes(v.image.value))).size == (10, 8)
    assert v.settle() is None  # nothing pending
    v.density.value = 0.4  # not a camera move: the full frame directly (re-coloured)
    assert v.history[-1]["level"] == 0 and v.history[-1]["map_tasks"] == 0
    timed = Viewer(pev, priv, width=10, height=8, settle=0.05, preview=1)
    timed.elevation.value = -30.0
    assert timed.history[-1]["level"] == 1
    deadline = time.time() + 20
    while timed.history[-1]["level"] != 0 and time.time() < deadline:
        time.sleep(0.05)
    assert timed.history[-1]["level"] == 0  # the timer rendered the full frame
    no = Viewer(pev, priv, width=10, height=8, preview=0)
    assert no.azimuth.continuous_update is False
    with pytest.raises(hevr.ParameterError, match="preview: expected a level of this store's pyramid, 0 to 1"):
        Viewer(pev, priv, preview=2, show=False)
    with pytest.raises(hevr.ParameterError, match="settle"):
        Viewer(pev, priv, settle=-1, show=False)


def test_gradient_box(scene, tmp_path):
    """On a store with the gradient channel the box shows; ticking it re-renders emphasis/TF with
    gradient=True (another channel: a map step) and matches render_plain(gradient=True)."""
    ev, priv, vol = scene
    gev = hevr.encrypt_volume(vol, tmp_path / "g.zarr", priv, brick=4, vector_dims=3, gradient=True, progress=False)
    hevr.clear_cache()
    v = Viewer(gev, priv, volume=vol, width=10, height=8, mode="tf")
    assert v.gradient.layout.display is None and "gradient" not in v.request()
    v.gradient.value = True
    last = v.history[-1]
    assert last["request"]["gradient"] is True and last["map_tasks"] > 0 and last["error"] <= last["bound"]
    v.mode.value = "emphasize"  # same channel (gradient), same camera: re-coloured
    assert v.history[-1]["map_tasks"] == 0 and v.history[-1]["request"]["gradient"] is True
    v.mode.value = "xray"
    n = len(v.history)
    v.gradient.value = False  # irrelevant in X-ray mode: no render
    assert len(v.history) == n and "gradient" not in v.request()
    plain = Viewer(ev, priv, width=10, height=8, show=False)
    assert plain.gradient.layout.display == "none"


def test_packed_store_orbits_its_axis_verified(tmp_path, keypair256):
    """A packed store: a parallel camera from the anterior view (orbiting the packing axis z), X-ray
    only, the settled frame verified and within error_bound of the slice reference; a drag along
    azimuth keeps serving, elevation stays below 45°."""
    pub, priv = keypair256
    vol = np.random.default_rng(2).integers(0, 256, (9, 8, 10)).astype(np.uint8)
    ev = hevr.encrypt_volume(vol, tmp_path / "p.zarr", priv, brick=4, layout="packed", progress=False)
    v = Viewer(ev, priv, volume=vol, width=12, height=10)
    first = v.history[-1]
    assert v.mode.options == ("xray",) and v.view == "anterior" and v.elevation.max < 45
    cam = v.camera()
    assert cam.parallel and cam == hevr.Camera.orbit(
        ev, azimuth=0, elevation=10, width=12, height=10, parallel=True, view="anterior"
    )
    assert "error_message" not in first and first["verified"] and first["map_tasks"] > 0
    assert first["error"] <= first["bound"] and "verified" in v.status.value
    for az in (60.0, 135.0, -100.0):
        v.azimuth.value = az
        last = v.history[-1]
        assert "error_message" not in last and last["verified"] and last["error"] <= last["bound"]
    v.view_angle.value = 15.0  # zoom: half the frame's height
    assert v.camera().parallel_scale == pytest.approx(cam.parallel_scale / 2)
    assert v.history[-1]["error"] <= v.history[-1]["bound"]


def test_packed_store_with_the_vector_channel_recolours(tmp_path, keypair256):
    """A packed store with the vector (and gradient) channel: TF frames verified, a colour change
    re-coloured in numpy (no map task), gradient modulation, within error_bound of the slice reference."""
    pub, priv = keypair256
    vol = np.random.default_rng(4).integers(0, 256, (9, 8, 10)).astype(np.uint8)
    ev = hevr.encrypt_volume(
        vol, tmp_path / "c.zarr", priv, brick=4, layout="packed", vector_dims=3, gradient=True, progress=False
    )
    v = Viewer(ev, priv, volume=vol, width=12, height=10, mode="tf")
    first = v.history[-1]
    assert v.mode.options == ("xray", "emphasize", "tf") and "error_message" not in first
    assert first["verified"] and first["map_tasks"] > 0 and first["error"] <= first["bound"]
    v.node_rows[0][1].value = "#00ff00"
    again = v.history[-1]
    assert again["client_recolour"] and again["map_tasks"] == 0 and again["error"] <= again["bound"]
    v.gradient.value = True  # the gradient channel: a render of g·e(d), verified
    mod = v.history[-1]
    assert mod["map_tasks"] > 0 and mod["verified"] and mod["error"] <= mod["bound"]
    v.mode.value = "xray"  # another channel: a render
    assert v.history[-1]["map_tasks"] > 0 and v.history[-1]["error"] <= v.history[-1]["bound"]
