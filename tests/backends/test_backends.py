"""The arithmetic backend seam (hevr.backends): selection, and a second backend giving the
identical image.

The second backend here is a deliberately naive one written from the textbook formulas with
Python ints (one ``pow`` per pair, no buckets, no Straus, no Horner): if the render graph,
the store or the client did any big-integer work outside the seam, or if the CPU backend's
optimisations changed a single bit, the packed ciphertexts of the two renders would differ.
"""

from __future__ import annotations

import sys

import dask
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import hevr
from hevr import backends
from hevr.backends import (
    Backend,
    CpuBackend,
    get_backend,
    register_backend,
    resolve_backend_name,
)
from hevr.rendering.encrypted import error_bound
from hevr.rendering.geometry.rays import cast_rays
from hevr.rendering.pipeline.graph import build_sums_graph
from hevr.rendering.pipeline.kernel import plan_products

SHAPE, BRICK, SPACING = (6, 7, 9), (3, 4, 4), (1.0, 0.9, 1.2)
NODES = [(0.2, "blue"), (0.6, "red"), (0.9, "#00ff00")]


class NaiveBackend(Backend):
    """Textbook Paillier arithmetic on Python ints; counts its calls."""

    name = "naive"

    def __init__(self) -> None:
        self.calls: dict[str, int] = {}

    def _count(self, op: str) -> None:
        self.calls[op] = self.calls.get(op, 0) + 1

    def from_bytes(self, records):
        self._count("from_bytes")
        return [int.from_bytes(bytes(r), "big") for r in np.asarray(records).reshape(-1, records.shape[-1])]

    def to_bytes(self, values, width):
        self._count("to_bytes")
        return (
            np.frombuffer(b"".join(int(v).to_bytes(width, "big") for v in values), np.uint8).reshape(-1, width).copy()
        )

    def residue_bytes(self, width):
        return sys.getsizeof(1 << (8 * width - 1)) + 8  # a Python int and its list slot

    def first_out_of_range(self, values, upper):
        self._count("first_out_of_range")
        return next((i for i, c in enumerate(values) if not 0 < c < upper), None)

    def encrypt(self, key, mantissas, *, unsafe_no_obfuscation=False):
        self._count("encrypt")
        pub = key.public_key if isinstance(key, hevr.PrivateKey) else key
        return [
            int(pub.encrypt(int(m), unsafe_no_obfuscation=unsafe_no_obfuscation))
            for m in np.asarray(mantissas).ravel().tolist()
        ]

    def decrypt(self, private_key, values):
        self._count("decrypt")
        n = int(private_key.public_key.n)
        lam = (int(private_key.p) - 1) * (int(private_key.q) - 1)
        mu = pow(lam, -1, n)  # g = n + 1: L(g^lam mod n²) = lam mod n
        return [(pow(int(c), lam, n * n) - 1) // n * mu % n for c in values]

    def ray_products(self, plan, components, nsquare, counter=None):
        self._count("ray_products")
        out = []
        for comp in components:
            rows = []
            for u in plan.rep:
                acc = 1
                if u >= 0:
                    _, s, e, _, _ = plan.tasks[u]
                    for v, w in zip(plan.vl[s:e], plan.wl[s:e]):
                        acc = acc * pow(int(comp[v]), int(w), nsquare) % nsquare
                rows.append(acc)
            out.append(rows)
        return out

    def segment_products(self, values, indptr, k, nsquare):
        self._count("segment_products")
        out = []
        for s, e in zip(indptr[:-1], indptr[1:]):
            for j in range(k):
                acc = 1
                for i in range(int(s), int(e)):
                    acc = acc * int(values[i * k + j]) % nsquare
                out.append(acc)
        return out

    def combine(self, values, comb, nsquare):
        self._count("combine")
        k, C = len(comb), len(comb[0])
        out = []
        for start in range(0, len(values), k):
            for ch in range(C):
                acc = 1
                for i in range(k):
                    acc = acc * pow(int(values[start + i]), comb[i][ch], nsquare) % nsquare
                out.append(acc)
        return out

    def pack(self, terms, exps, pack_bits, per_pack, offset, n):
        self._count("pack")
        n2 = n * n
        J = max(1, per_pack)
        out = []
        for start in range(0, len(terms), J):
            acc = 1
            for j, (t, r) in enumerate(zip(terms[start : start + J], exps[start : start + J])):
                value = pow(int(t), int(r), n2) * pow(n + 1, offset, n2) % n2  # T^R ⊕ O
                acc = acc * pow(value, 1 << (pack_bits * j), n2) % n2
            out.append(acc)
        return out


@pytest.fixture
def naive():
    inst = NaiveBackend()
    register_backend("naive", lambda: inst)
    try:
        yield inst
    finally:
        backends._FACTORIES.pop("naive", None)
        backends._INSTANCES.pop("naive", None)


@pytest.fixture(scope="module")
def volume():
    rng = np.random.default_rng(11)
    vol = rng.integers(-300, 900, SHAPE).astype(np.int16)  # signed: the planner's offset is used
    return vol


@pytest.fixture(scope="module")
def store(tmp_path_factory, keypair256, volume):
    path = tmp_path_factory.mktemp("backends") / "v.zarr"
    with dask.config.set(scheduler="sync"):
        return hevr.encrypt_volume(
            volume,
            path,
            keypair256[1],
            brick=BRICK,
            spacing=SPACING,
            vector_dims=3,
            value_range=(-300, 900),
            progress=False,
        )


CASES = [
    ("xray", "nearest", {}),
    ("xray", "trilinear", {}),
    ("emphasize", "nearest", {"density": 0.5}),
    ("tf", "trilinear", {"nodes": NODES}),
]


@pytest.mark.parametrize("mode, sampling, kw", CASES, ids=[f"{m}-{s}" for m, s, _ in CASES])
def test_second_backend_gives_the_identical_image(store, volume, keypair256, naive, mode, sampling, kw):
    _, priv = keypair256
    cam = hevr.Camera.orbit(store, azimuth=40, elevation=20, width=9, height=8)
    with dask.config.set(scheduler="sync"):
        a = hevr.render(store, cam, mode=mode, sampling=sampling, progress=False, cache=False, backend="cpu", **kw)
        b = hevr.render(store, cam, mode=mode, sampling=sampling, progress=False, cache=False, backend="naive", **kw)
    assert naive.calls.get("ray_products", 0) > 0 and naive.calls.get("pack", 0) > 0
    assert len(a.ciphertexts) == len(b.ciphertexts)
    for ta, tb in zip(a.ciphertexts, b.ciphertexts):
        np.testing.assert_array_equal(ta, tb)
    got = b.decrypt(priv, backend="naive")
    np.testing.assert_array_equal(got, a.decrypt(priv))
    ref = hevr.render_plain(
        volume, cam, mode=mode, sampling=sampling, spacing=SPACING, vector_dims=3, value_range=(-300, 900), **kw
    )
    assert np.all(np.abs(got - ref) <= error_bound(store, cam, mode, sampling, **kw))
    assert np.count_nonzero(ref) > 5


def test_dask_config_key_selects_the_backend(store, naive):
    cam = hevr.Camera.orbit(store, azimuth=10, elevation=5, width=6, height=6)
    assert resolve_backend_name(None) == "cpu" and isinstance(get_backend(), CpuBackend)
    with dask.config.set({"hevr.backend": "naive", "scheduler": "sync"}):
        assert get_backend().name == "naive"
        hevr.render(store, cam, progress=False, cache=False)
    assert naive.calls.get("ray_products", 0) > 0
    before = dict(naive.calls)
    with dask.config.set(scheduler="sync"):
        hevr.render(store, cam, progress=False, cache=False)  # default again: cpu
    assert naive.calls == before


def _task_args(graph) -> list:
    """Every argument of every task (dask's Task objects; older dask: tuples)."""
    out = []
    for task in dict(graph).values():
        args = getattr(task, "args", None)
        out.extend(args if args is not None else (task[1:] if isinstance(task, tuple) else ()))
    return out


def test_graph_holds_the_backend_name_not_an_object(store):
    cam = hevr.Camera.orbit(store, azimuth=10, elevation=5, width=6, height=6)
    rays = cast_rays(cam, store.shape, store.spacing, 1.0)
    g = build_sums_graph(store, cam, rays, "nearest", 1.0, 0, "scalar", 4, 4, "cpu")
    n_map = g.map_tasks
    assert n_map > 0
    args = _task_args(g.dsk)
    assert args and not any(isinstance(a, Backend) for a in args)
    assert "cpu" in args  # map and merge tasks carry the name; each worker builds its own backend


def test_unknown_backend_is_refused_by_name(store, keypair256, tmp_path):
    cam = hevr.Camera.orbit(store, width=4, height=4)
    with pytest.raises(hevr.ParameterError, match="backend: expected 'auto' or one of 'cpu'.*got 'abacus'"):
        hevr.render(store, cam, backend="abacus", progress=False)
    with pytest.raises(hevr.ParameterError, match="backend: expected"):
        hevr.encrypt_volume(
            np.zeros((2, 2, 2), np.uint8), tmp_path / "x.zarr", keypair256[0], backend="abacus", progress=False
        )
    assert not (tmp_path / "x.zarr").exists()  # refused before anything was written
    with dask.config.set({"hevr.backend": "abacus"}), pytest.raises(hevr.ParameterError, match="got 'abacus'"):
        get_backend()
    with pytest.raises(hevr.ParameterError, match="backend: expected 'auto' or one of"):
        resolve_backend_name(["cpu"])  # unhashable: still a clear ParameterError
    with pytest.raises(hevr.ParameterError, match="name: expected a backend name"):
        register_backend("not a name", CpuBackend)


def test_encryption_and_brick_reads_through_a_backend(keypair256, tmp_path, naive):
    pub, priv = keypair256
    vol = np.arange(2 * 3 * 4, dtype=np.int16).reshape(2, 3, 4) - 7
    with dask.config.set(scheduler="sync"):
        ev = hevr.encrypt_volume(vol, tmp_path / "n.zarr", pub, brick=2, backend="naive", progress=False)
    assert naive.calls.get("encrypt", 0) == ev.meta.n_bricks
    got = np.zeros(vol.shape, np.int64)
    for idx in ev.brick_indices():
        sl = ev.brick_slices(idx)
        cts = ev.read_brick(idx, backend="naive")
        assert all(type(c) is int for c in cts)  # the backend's own form
        got[sl] = np.array(priv.decrypt_array(cts)).reshape(ev.brick_shape(idx))
    np.testing.assert_array_equal(got, vol)


# -- the CPU backend against the textbook formulas, operation by operation -------------------
N = 1000003 * 999983  # a small modulus n (the arithmetic does not need primes to be tested)
N2 = N * N
residues = st.lists(st.integers(1, N2 - 1), min_size=1, max_size=12)


@settings(max_examples=40, deadline=None)
@given(values=residues, k=st.integers(1, 3), data=st.data())
def test_cpu_segment_products(values, k, data):
    rows = len(values) // k or 1
    values = (values * k)[: rows * k]
    cuts = sorted(set(data.draw(st.lists(st.integers(1, rows), max_size=4)) + [rows]))
    indptr = np.array([0] + cuts)
    cpu = CpuBackend()
    mp = cpu.from_bytes(NaiveBackend().to_bytes(values, 16))
    got = [int(v) for v in cpu.segment_products(mp, indptr, k, N2)]
    assert got == NaiveBackend().segment_products(values, indptr, k, N2)


@settings(max_examples=40, deadline=None)
@given(data=st.data(), k=st.integers(1, 9), C=st.integers(1, 3), pixels=st.integers(1, 3))
def test_cpu_combine(data, k, C, pixels):
    values = data.draw(st.lists(st.integers(1, N2 - 1), min_size=k * pixels, max_size=k * pixels))
    comb = data.draw(st.lists(st.lists(st.integers(0, 5000), min_size=C, max_size=C), min_size=k, max_size=k))
    got = [int(v) for v in CpuBackend().combine(CpuBackend().from_bytes(NaiveBackend().to_bytes(values, 16)), comb, N2)]
    assert got == NaiveBackend().combine(values, comb, N2)


@settings(max_examples=40, deadline=None)
@given(data=st.data(), per_pack=st.integers(1, 4), bits=st.integers(4, 12), offset=st.integers(0, 50))
def test_cpu_pack(data, per_pack, bits, offset):
    m = data.draw(st.integers(1, 9))
    terms = data.draw(st.lists(st.integers(1, N2 - 1), min_size=m, max_size=m))
    exps = data.draw(st.lists(st.integers(0, (1 << bits) - 1), min_size=m, max_size=m))
    cpu = CpuBackend()
    got = [
        int(v) for v in cpu.pack(cpu.from_bytes(NaiveBackend().to_bytes(terms, 16)), exps, bits, per_pack, offset, N)
    ]
    assert got == NaiveBackend().pack(terms, exps, bits, per_pack, offset, N)


@settings(max_examples=40, deadline=None)
@given(data=st.data(), n_vox=st.integers(1, 8), rows=st.integers(1, 6), wmax=st.sampled_from([1, 2, 1023, 70000]))
def test_cpu_ray_products(data, n_vox, rows, wmax):
    comps = [data.draw(st.lists(st.integers(1, N2 - 1), min_size=n_vox, max_size=n_vox)) for _ in range(2)]
    lens = data.draw(st.lists(st.integers(0, 10), min_size=rows, max_size=rows))
    indptr = np.concatenate([[0], np.cumsum(lens)]).astype(np.int64)
    voxels = np.array(
        data.draw(st.lists(st.integers(0, n_vox - 1), min_size=int(indptr[-1]), max_size=int(indptr[-1]))),
        dtype=np.int64,
    )
    weights = np.array(
        data.draw(st.lists(st.integers(0, wmax), min_size=voxels.size, max_size=voxels.size)), dtype=np.int64
    )
    plan = plan_products(indptr, voxels, weights, n_vox)
    cpu = CpuBackend()
    got = cpu.ray_products(plan, [cpu.from_bytes(NaiveBackend().to_bytes(c, 16)) for c in comps], N2)
    want = NaiveBackend().ray_products(plan, comps, N2)
    assert [[int(v) for v in g] for g in got] == want
    # and the plan itself is the CSR's products, whatever the method chosen per row
    direct = [1] * rows
    for r in range(rows):
        acc = 1
        for i in range(indptr[r], indptr[r + 1]):
            acc = acc * pow(comps[0][voxels[i]], int(weights[i]), N2) % N2
        direct[r] = acc
    assert want[0] == direct
