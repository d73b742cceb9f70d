"""Colour on the client (hevr.colour, finish="client"): accuracy against render_plain for every mode,
re-colouring without a server, the colouring never reaching the graph, a file or a log, the v3
image format, and render_frame's streamed decryption."""

from __future__ import annotations

import hashlib
import json
import logging
import pickle
import struct

import dask
import numpy as np
import pytest
from dask.callbacks import Callback
from distributed import WorkerPlugin
from hypothesis import given, settings
from hypothesis import strategies as st

import hevr
from hevr.core.limits import integrity_bits
from hevr.rendering.planning.planner import plan_sums
from hevr.store.metadata import ChannelInfo
from hevr.store.packing import mantissa_range as _mantissa_range

# values no render would produce by chance: found in pickled bytes if they leak
SECRET_DENSITY = 0.613579
SECRET_NODES = [(0.271828, (0.314159, 0.161803, 0.577215)), (0.832716, (0.141421, 0.732050, 0.223606))]
SECRET_FLOATS = [SECRET_DENSITY, 0.271828, 0.314159, 0.161803, 0.577215, 0.832716, 0.141421, 0.732050, 0.223606]


@pytest.fixture(scope="module")
def scene(tmp_path_factory, keypair256):
    rng = np.random.default_rng(3)
    vol = rng.integers(0, 256, (9, 10, 11)).astype(np.uint8)
    with dask.config.set(scheduler="sync"):
        ev = hevr.encrypt_volume(
            vol,
            tmp_path_factory.mktemp("c") / "v.zarr",
            keypair256[1],
            brick=4,
            vector_dims=3,
            gradient=True,
            progress=False,
        )
        hevr.build_pyramid(ev, levels=1, progress=False)
    ev = hevr.open_volume(ev.path)
    return ev, vol, keypair256[1], hevr.Camera.orbit(ev, azimuth=35, elevation=15, width=9, height=8)


MODES = [
    ("xray", {}),
    ("emphasize", {"density": 0.45}),
    ("tf", {"nodes": [(0.2, "red"), (0.7, "#00f")]}),
    ("tf", {"nodes": [(0.3, "lime"), (0.9, "white")], "gradient": True}),
]


@pytest.mark.parametrize("sampling", ["nearest", "trilinear"])
@pytest.mark.parametrize("level", [None, 1])
@pytest.mark.parametrize("mode, kw", MODES, ids=["xray", "emphasize", "tf", "tf-gradient"])
def test_every_mode_within_the_client_bound(scene, mode, kw, sampling, level):
    ev, vol, priv, cam = scene
    img = hevr.render(ev, cam, mode=mode, sampling=sampling, level=level, progress=False, cache=False, **kw)
    assert img.finish == "client" and img.colouring is not None
    got = img.decrypt(priv)
    ref = hevr.render_plain(vol, cam, mode=mode, sampling=sampling, vector_dims=3, level=level or 0, **kw)
    bound = hevr.error_bound(ev, cam, mode, sampling, level=level, **kw)
    assert got.shape == ref.shape and np.count_nonzero(ref) > 5
    assert (np.abs(got - ref) <= bound).all(), float(np.abs(got - ref).max())
    server_bound = hevr.error_bound(ev, cam, mode, sampling, level=level, finish="server", **kw)
    assert (bound <= server_bound).all() and (bound < server_bound).any()  # no reciprocal, no matrix rounding


@pytest.mark.parametrize("mode, kw", MODES[:3], ids=["xray", "emphasize", "tf"])
def test_slices_within_the_client_bound(scene, mode, kw):
    ev, vol, priv, _ = scene
    for plane in (hevr.Plane.axial(ev, 4, slab=3), hevr.Plane.sagittal(ev, 2)):
        img = hevr.render_slice(ev, plane, mode=mode, progress=False, **kw)
        got = img.decrypt(priv)
        ref = hevr.render_slice_plain(vol, plane, mode=mode, vector_dims=3, **kw)
        assert (np.abs(got - ref) <= hevr.error_bound(ev, plane, mode, **kw)).all()


def test_recolour_on_the_client_equals_a_render(scene):
    ev, vol, priv, cam = scene
    img = hevr.render(ev, cam, mode="tf", nodes=MODES[2][1]["nodes"], progress=False, cache=False)
    frame = img.decrypt_frame(priv)
    assert np.array_equal(frame.image, img.decrypt(priv)) and "0." not in repr(frame)
    for mode, kw in MODES[1:3] + [("tf", {"nodes": [(0.5, "orange")]})]:
        direct = hevr.render(ev, cam, mode=mode, progress=False, cache=False, **kw).decrypt(priv)
        assert np.array_equal(frame.recolour(mode, **kw), direct)  # the same sums, the same numpy
        assert np.array_equal(img.decrypt(priv, mode=mode, **kw), direct)
    assert np.array_equal(frame.recolour(density=0.45), frame.recolour("emphasize", 0.45))
    with pytest.raises(hevr.ParameterError, match="^mode: expected 'emphasize' or 'tf' for a frame of the vector"):
        frame.recolour("xray")
    with pytest.raises(hevr.ParameterError, match="^nodes\\[0\\]"):
        frame.recolour(nodes=[(2.0, "red")])
    xray = hevr.render(ev, cam, progress=False).decrypt_frame(priv)
    with pytest.raises(hevr.ParameterError, match="^mode: expected 'xray' for a frame of the scalar"):
        xray.recolour(nodes=[(0.5, "red")])
    server = hevr.render(ev, cam, progress=False, finish="server")
    with pytest.raises(hevr.ParameterError, match="^finish: expected an image rendered with finish='client'"):
        server.decrypt_frame(priv)
    with pytest.raises(hevr.ParameterError, match="^mode, density, nodes: expected none"):
        server.decrypt(priv, density=0.5)


def test_server_finishing_is_unchanged_and_recolours_from_sums(scene, tmp_path):
    ev, vol, priv, cam = scene
    nodes = MODES[2][1]["nodes"]
    a = hevr.render(
        ev, cam, mode="tf", nodes=nodes, progress=False, cache=False, finish="server", keep_sums=tmp_path / "s.hevrsums"
    )
    b = hevr.recolour(tmp_path / "s.hevrsums", mode="tf", nodes=nodes, finish="server", progress=False)
    assert (
        a.finish == "server"
        and a.info["nodes"]
        and [c.tobytes() for c in a.ciphertexts] == [c.tobytes() for c in b.ciphertexts]
    )
    c = hevr.recolour(tmp_path / "s.hevrsums", mode="tf", nodes=nodes, progress=False)  # client by default
    assert c.finish == "client" and np.array_equal(
        c.decrypt(priv), hevr.render(ev, cam, mode="tf", nodes=nodes, progress=False, cache=False).decrypt(priv)
    )


# -- the colouring stays on the client -------------------------------------------------------
def _leaks(blob: bytes) -> list:
    """The secret floats found in ``blob``: as float64 bytes or as text."""
    found = []
    for x in SECRET_FLOATS:
        if struct.pack("<d", x) in blob or struct.pack(">d", x) in blob or repr(x).encode() in blob:
            found.append(x)
    return found


class _Graphs(Callback):
    """Every graph the local scheduler runs, pickled, and every task's arguments."""

    def __init__(self):
        super().__init__()
        self.blobs: list[bytes] = []

    def _start(self, dsk):
        self.blobs.append(pickle.dumps(dict(dsk)))

    def _pretask(self, key, dsk, state):
        self.blobs.append(pickle.dumps(dsk[key]))


@pytest.mark.parametrize("finish", ["client", "server"])
def test_the_colouring_never_reaches_graph_file_or_log(scene, tmp_path, caplog, finish):
    ev, _, priv, cam = scene
    caplog.set_level(logging.DEBUG)
    graphs = _Graphs()
    with graphs, dask.config.set(scheduler="threads"):
        tf = hevr.render(ev, cam, mode="tf", nodes=SECRET_NODES, progress=False, cache=False, finish=finish)
        em = hevr.render(ev, cam, mode="emphasize", density=SECRET_DENSITY, progress=False, finish=finish)
        deferred = hevr.render(ev, cam, mode="tf", nodes=SECRET_NODES, compute=False, cache=False, finish=finish)
        em_deferred = hevr.render(ev, cam, mode="emphasize", density=SECRET_DENSITY, compute=False, finish=finish)
    tf.save(tmp_path / "tf.hevr")
    em.save(tmp_path / "em.hevr")
    worker_side = b"".join(graphs.blobs) + pickle.dumps(dict(deferred.dask)) + pickle.dumps(dict(em_deferred.dask))
    files = (tmp_path / "tf.hevr").read_bytes() + (tmp_path / "em.hevr").read_bytes()
    logs = "\n".join(r.getMessage() for r in caplog.records).encode()
    if finish == "server":  # the check finds what the paper's way sends
        assert _leaks(worker_side) and _leaks(files)
        return
    assert graphs.blobs and not _leaks(worker_side), _leaks(worker_side)
    assert not _leaks(files) and not _leaks(logs)
    # not even which of the two vector modes: the tasks and the file know the vector channel only
    assert b"emphasize" not in worker_side and b"emphasize" not in (tmp_path / "em.hevr").read_bytes()
    assert em.shape == (8, 9) and tf.shape == (8, 9, 3) and hevr.load_image(tmp_path / "tf.hevr").shape == (8, 9)
    assert "nodes" not in tf.info and "density" not in em.info and "colouring" not in repr(tf)
    assert tf.colouring is not None and pickle.loads(pickle.dumps(tf)).colouring is None  # not even when shipped
    assert np.array_equal(hevr.load_image(tmp_path / "tf.hevr").decrypt(priv, nodes=SECRET_NODES), tf.decrypt(priv))
    with pytest.raises(hevr.ParameterError, match="^nodes: expected a transfer function"):
        hevr.load_image(tmp_path / "tf.hevr").decrypt(priv)


def _worker_specs(cluster, run) -> bytes:
    """Every task spec the workers executed while ``run()`` ran, pickled (a worker plugin)."""

    class Record(WorkerPlugin):  # local: pickled by value for the worker processes
        name = "hevr-test-specs"

        def setup(self, worker):
            self.worker, self.seen = worker, []

        def transition(self, key, start, finish, **kwargs):
            ts = self.worker.state.tasks.get(key)
            if finish == "executing" and ts is not None:
                self.seen.append(pickle.dumps(ts.run_spec))

    cluster.register_plugin(Record(), name="hevr-test-specs")
    try:
        run()
        blobs = cluster.run(lambda dask_worker: b"".join(dask_worker.plugins["hevr-test-specs"].seen))
    finally:
        cluster.unregister_worker_plugin("hevr-test-specs")
    return b"".join(blobs.values())


def test_the_colouring_never_reaches_a_cluster(scene, cluster):
    ev, vol, priv, cam = scene
    out = {}

    def client_finished():
        out["frame"] = hevr.render_frame(
            ev, cam, priv, mode="tf", nodes=SECRET_NODES, client=cluster, progress=False, cache=False
        )
        hevr.render(ev, cam, mode="emphasize", density=SECRET_DENSITY, client=cluster, progress=False, cache=False)

    seen = _worker_specs(cluster, client_finished)
    assert len(seen) > 10000 and not _leaks(seen) and b"emphasize" not in seen  # the tasks ran; nothing leaked
    server = _worker_specs(
        cluster,
        lambda: hevr.render(
            ev,
            cam,
            mode="emphasize",
            density=SECRET_DENSITY,
            client=cluster,
            progress=False,
            cache=False,
            finish="server",
        ),
    )
    # the check sees what the paper's way sends to the workers: its plan names the mode and carries
    # the density as the quantised combination matrix (integers, so no float of it travels either way)
    assert b"emphasize" in server and not _leaks(server)
    frame = out["frame"]
    ref = hevr.render_plain(vol, cam, mode="tf", nodes=SECRET_NODES, vector_dims=3)
    assert (np.abs(frame.image - ref) <= hevr.error_bound(ev, cam, "tf", nodes=SECRET_NODES)).all()
    assert frame.stats["seconds"] > 0 and frame.stats["ciphertexts"] > 0


# -- render_frame ------------------------------------------------------------------------------
def test_render_frame_streams_the_same_frame(scene, cluster):
    ev, vol, priv, cam = scene
    nodes = MODES[2][1]["nodes"]
    want = hevr.render(ev, cam, mode="tf", nodes=nodes, progress=False, cache=False, tile=4).decrypt(priv)
    for client in (None, cluster):
        frame = hevr.render_frame(
            ev, cam, priv, mode="tf", nodes=nodes, client=client, progress=False, tile=4, cache=False
        )
        assert np.array_equal(frame.image, want) and frame.stats["finish_tasks"] > 1
    hevr.clear_cache()  # a cached view: another colouring is served from the packed sums, with no task
    a = hevr.render_frame(ev, cam, priv, mode="tf", nodes=nodes, progress=False, tile=4)
    b = hevr.render_frame(ev, cam, priv, mode="emphasize", density=0.4, progress=False, tile=4)
    assert b.stats["finish_tasks"] == 0 and b.stats["reused_ray_sums"] and np.array_equal(b.means, a.means)
    plane = hevr.Plane.axial(ev, 3)
    assert np.abs(hevr.render_frame(ev, plane, priv, progress=False).image - vol[3]).max() <= 1e-9
    with pytest.raises(hevr.ParameterError, match="^finish: expected no finish="):
        hevr.render_frame(ev, cam, priv, finish="server")
    with pytest.raises(hevr.ParameterError, match="^private_key: expected a hevr.PrivateKey"):
        hevr.render_frame(ev, cam, priv.public_key)
    with pytest.raises(hevr.ParameterError, match=r"^tiles: expected a keyword of hevr.render \(backend, cache"):
        hevr.render_frame(ev, cam, priv, tiles=4)
    with pytest.raises(hevr.ParameterError, match="^level: expected None for a hevr.Plane"):
        hevr.render_frame(ev, plane, priv, level=1)


def test_a_tampered_unit_is_an_integrity_error(scene, monkeypatch):
    ev, _, priv, cam = scene
    from hevr.rendering.pipeline import stream

    real = stream.StreamDecryptor.unit

    def flip(self, i, packed):
        packed = packed.copy()
        if i == 0 and len(packed):
            packed[0, -1] ^= 1
        return real(self, i, packed)

    monkeypatch.setattr(stream.StreamDecryptor, "unit", flip)
    with pytest.raises(hevr.IntegrityError, match="no image is returned"):
        hevr.render_frame(ev, cam, priv, progress=False, cache=False)


# -- the v3 file ---------------------------------------------------------------------------------
def _header(blob: bytes) -> tuple[dict, int]:
    (hl,) = struct.unpack("<I", blob[8:12])
    return json.loads(blob[12 : 12 + hl]), hl


def _rewrite(blob: bytes, head: dict, body: bytes | None = None, magic: bytes | None = None) -> bytes:
    _, hl = _header(blob)
    raw = json.dumps(head).encode()
    out = (magic or blob[:8]) + struct.pack("<I", len(raw)) + raw + (blob[12 + hl : -32] if body is None else body)
    return out + hashlib.sha256(out).digest()


def test_client_frame_file_round_trip_and_samples_checked(scene, tmp_path):
    ev, _, priv, cam = scene
    img = hevr.render(ev, cam, progress=False, cache=False)
    path = tmp_path / "x.hevr"
    img.save(path)
    blob = path.read_bytes()
    head, hl = _header(blob)
    assert blob[:8] == b"HEVRIMG\x03" and head["finish"] == "client" and head["components"] == 1
    back = hevr.load_image(path)
    assert np.array_equal(back.samples, img.samples) and np.array_equal(back.decrypt(priv), img.decrypt(priv))
    body = bytearray(blob[12 + hl : -32])
    H, W = img.shape
    miss = int(np.flatnonzero(img.samples.ravel() == 0)[0])
    body[len(body) - 4 * (H * W - miss)] = 1  # a missed pixel given a sample: the mask disagrees
    (tmp_path / "bad.hevr").write_bytes(_rewrite(blob, head, bytes(body)))
    with pytest.raises(hevr.CorruptStoreError, match="header field 'hits': expected the pixels whose sample count"):
        hevr.load_image(tmp_path / "bad.hevr")
    (tmp_path / "short.hevr").write_bytes(_rewrite(blob, head, blob[12 + hl : -36]))
    with pytest.raises(hevr.CorruptStoreError, match="truncated: .* bytes of sample counts"):
        hevr.load_image(tmp_path / "short.hevr")
    for field, value, pattern in (
        ("finish", "edge", "'finish': expected 'server' or 'client'"),
        ("components", 3, "'components': expected an int in \\[1, 1\\]"),
        ("channel", "colour", "'channel': expected one of"),
    ):
        (tmp_path / "f.hevr").write_bytes(_rewrite(blob, dict(head, **{field: value})))
        with pytest.raises(hevr.CorruptStoreError, match=pattern):
            hevr.load_image(tmp_path / "f.hevr")


def test_version_2_files_still_load(scene, tmp_path):
    ev, _, priv, cam = scene
    img = hevr.render(ev, cam, mode="tf", nodes=MODES[2][1]["nodes"], progress=False, finish="server")
    img.save(tmp_path / "v3.hevr")
    blob = (tmp_path / "v3.hevr").read_bytes()
    head, _ = _header(blob)
    old = {k: v for k, v in head.items() if k not in ("finish", "channel", "components")}
    (tmp_path / "v2.hevr").write_bytes(_rewrite(blob, dict(old, version=2), magic=b"HEVRIMG\x02"))
    back = hevr.load_image(tmp_path / "v2.hevr")
    assert back.finish == "server" and np.array_equal(back.decrypt(priv), img.decrypt(priv))


# -- the planner of the sums -------------------------------------------------------------------------
@settings(max_examples=60, deadline=None)
@given(
    lo=st.integers(-(10**6), 10**6),
    span=st.integers(0, 10**6),
    exp=st.integers(-6, 2),
    counts=st.lists(st.integers(0, 400), min_size=1, max_size=20),
    trilinear=st.booleans(),
    bits=st.sampled_from([256, 512, 2048]),
)
def test_plan_sums_bounds_every_sum(lo, span, exp, counts, trilinear, bits):
    hi = lo + span
    meta = type(
        "M", (), {"scalar": ChannelInfo(exponent=exp, digits=None), "value_range": (lo * 10.0**exp, hi * 10.0**exp)}
    )()
    n = (1 << (bits - 1)) + 1
    try:
        p = plan_sums(
            n=n,
            channel="scalar",
            sampling="trilinear" if trilinear else "nearest",
            meta=meta,
            n_samples=np.array(counts),
            digits=3 if trilinear else 0,
            pack=True,
        )
    except hevr.RenderPlanError:
        return
    per = (10**3 + 4) if trilinear else 1
    w = max(counts) * per
    lo_m, hi_m = _mantissa_range(meta.value_range, exp)  # the stored mantissas' range
    # every sum S in [lo_m·W, hi_m·W] lands in [0, bound] after the offset, within the packing width
    assert p.offset + min(lo_m, 0) * w >= 0 and p.offset + max(hi_m, 0) * w <= p.bound < 2**p.pack_bits
    assert p.pack_bits * p.per_pack <= bits - 1 - integrity_bits(bits)  # the integrity margin is kept
    assert p.comb is None and p.factor == 1 and p.finish == "client"


def test_cached_packed_sums_are_not_shared_with_an_image(scene):
    """Changing an image's ciphertexts in place cannot reach the next render of the view."""
    ev, _, priv, cam = scene
    hevr.clear_cache()
    first = hevr.render(ev, cam, mode="tf", nodes=MODES[2][1]["nodes"], progress=False)
    want = first.decrypt(priv)
    for c in first.ciphertexts:
        c[...] = 0
    again = hevr.render(ev, cam, mode="tf", nodes=MODES[2][1]["nodes"], progress=False)
    assert again.stats["finish_tasks"] == 0 and np.array_equal(again.decrypt(priv), want)
    for c in again.ciphertexts:
        c[...] = 0
    assert np.array_equal(
        hevr.render(ev, cam, density=0.3, mode="emphasize", progress=False).decrypt(priv),
        hevr.render(ev, cam, density=0.3, mode="emphasize", progress=False, cache=False).decrypt(priv),
    )
