"""hevr.store.writer.encrypt_volume: round trips, secrets scan, resume, bad input, overwrite."""

from __future__ import annotations

import hashlib
import json
import warnings
from pathlib import Path

import dask
import dask.array as da
import fsspec
import numpy as np
import pytest
import zarr

import hevr
from hevr.store import writer as store_mod
from hevr.volume.density import encode_density, normalize_density

SHAPE = (5, 7, 9)
BRICK = (2, 3, 4)  # 3 x 3 x 3 bricks, ragged at every edge


def _decrypt_scalar(ev, priv):
    out = np.zeros(ev.shape, dtype=object)
    for idx in ev.brick_indices():
        sl = ev.brick_slices(idx)
        out[sl] = np.array(priv.decrypt_array(ev.read_brick(idx)), dtype=object).reshape(ev.brick_shape(idx))
    return out


def _decrypt_vector(ev, priv):
    k = ev.vector_dims
    out = np.zeros((k,) + ev.shape, dtype=object)
    for idx in ev.brick_indices():
        sl = ev.brick_slices(idx)
        for j, cts in enumerate(ev.read_brick(idx, "vector")):
            out[(j,) + sl] = np.array(priv.decrypt_array(cts), dtype=object).reshape(ev.brick_shape(idx))
    return out


def _vol(dtype):
    rng = np.random.default_rng(7)
    if dtype == "uint8":
        return rng.integers(0, 256, SHAPE).astype(np.uint8)
    if dtype == "int16":
        return rng.integers(-1024, 3000, SHAPE).astype(np.int16)
    return (rng.random(SHAPE) * 10 - 5).astype(np.float32)


@pytest.mark.parametrize("dtype", ["uint8", "int16", "float32"])
@pytest.mark.parametrize("owner", [True, False], ids=["owner", "public"])
def test_scalar_round_trip(tmp_path, keypair256, dtype, owner):
    pub, priv = keypair256
    vol = _vol(dtype)
    kw = {"value_range": (-5, 5)} if dtype == "float32" else {}
    ev = hevr.encrypt_volume(
        vol, tmp_path / "v.zarr", priv if owner else pub, brick=BRICK, spacing=(1.0, 2.0, 0.5), progress=False, **kw
    )
    assert ev.grid == (3, 3, 3) and ev.shape == SHAPE and ev.spacing == (1.0, 2.0, 0.5)
    got = _decrypt_scalar(hevr.open_volume(tmp_path / "v.zarr"), priv)
    if dtype == "float32":
        assert ev.meta.scalar.exponent == -3
        assert np.abs(got.astype(np.float64) * 1e-3 - vol).max() <= 0.5e-3 + 1e-6
    else:
        assert ev.meta.scalar.exponent == 0
        assert np.array_equal(got.astype(np.int64), vol.astype(np.int64))


@pytest.mark.parametrize("k", [2, 4])
def test_vector_channel_round_trip(tmp_path, keypair256, k):
    pub, priv = keypair256
    vol = _vol("uint8")
    ev = hevr.encrypt_volume(
        vol, tmp_path / "v.zarr", priv, brick=BRICK, scalar=False, vector_dims=k, vector_digits=4, progress=False
    )
    assert not ev.has_scalar and ev.vector_dims == k and ev.value_range == (0.0, 255.0)
    got = _decrypt_vector(ev, priv).astype(np.float64) * 1e-4
    expected = np.moveaxis(encode_density(normalize_density(vol, (0, 255)), k), -1, 0)
    assert np.abs(got - expected).max() <= 0.5e-4 + 1e-12


def test_dask_array_input_and_distributed_client(tmp_path, keypair256):
    from distributed import Client, LocalCluster

    pub, priv = keypair256
    vol = _vol("int16")
    with (
        LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0") as cluster,
        Client(cluster) as client,
    ):
        ev = hevr.encrypt_volume(
            da.from_array(vol, chunks=(3, 3, 3)),
            tmp_path / "v.zarr",
            priv,
            brick=BRICK,
            vector_dims=3,
            progress=False,
            client=client,
        )
    assert np.array_equal(_decrypt_scalar(ev, priv).astype(np.int64), vol.astype(np.int64))


def _secret_forms(priv):
    p, q = int(priv.p), int(priv.q)
    lam = (p - 1) * (q - 1)
    import math

    lcm = lam // math.gcd(p - 1, q - 1)
    forms = []
    for x in (p, q, lam, lcm):
        forms += [
            str(x).encode(),
            format(x, "x").encode(),
            format(x, "X").encode(),
            x.to_bytes((x.bit_length() + 7) // 8, "big"),
            x.to_bytes((x.bit_length() + 7) // 8, "little"),
        ]
    return forms


def test_no_secret_in_any_file(tmp_path, keypair256):
    pub, priv = keypair256
    ev = hevr.encrypt_volume(_vol("uint8"), tmp_path / "v.zarr", priv, brick=BRICK, vector_dims=2, progress=False)
    files = [f for f in Path(ev.path).rglob("*") if f.is_file()]
    assert len(files) > 27
    forms = _secret_forms(priv)
    for f in files:
        blob = f.read_bytes()
        for s in forms:
            assert s not in blob, f"secret material found in {f}"
    meta = json.loads((Path(ev.path) / "zarr.json").read_text())
    assert meta["attributes"]["hevr"]["public_key"]["n"] == str(int(pub.n))


def test_resume_after_interrupted_run(tmp_path, keypair256, monkeypatch):
    pub, priv = keypair256
    vol = _vol("uint8")
    path = tmp_path / "v.zarr"
    real = store_mod._encrypt_brick
    calls = []

    def flaky(*args, **kw):
        if len(calls) >= 10:
            raise RuntimeError("worker died")
        calls.append(args[2])
        return real(*args, **kw)

    monkeypatch.setattr(store_mod, "_encrypt_brick", flaky)
    with dask.config.set(scheduler="synchronous"), pytest.raises(RuntimeError, match="worker died"):
        hevr.encrypt_volume(vol, path, priv, brick=BRICK, vector_dims=2, progress=False)
    with pytest.raises(hevr.IncompleteStoreError, match="17 of 27 bricks missing"):
        hevr.open_volume(path)
    with pytest.raises(hevr.StoreExistsError):
        hevr.encrypt_volume(vol, path, priv, brick=BRICK, vector_dims=2, progress=False)
    done_first = set(calls)
    calls.clear()
    monkeypatch.setattr(store_mod, "_encrypt_brick", lambda *a, **k: (calls.append(a[2]), real(*a, **k))[1])
    with dask.config.set(scheduler="synchronous"):
        ev = hevr.encrypt_volume(vol, path, priv, brick=BRICK, vector_dims=2, progress=False, resume=True)
    assert len(calls) == 17 and not (set(calls) & done_first)
    assert np.array_equal(_decrypt_scalar(ev, priv).astype(np.int64), vol.astype(np.int64))
    hevr.open_volume(path, verify="full")


def test_resume_with_another_key_is_refused(tmp_path, keypair256, keypair512):
    vol = _vol("uint8")
    path = tmp_path / "v.zarr"
    hevr.encrypt_volume(vol, path, keypair256[0], brick=BRICK, progress=False)
    before = {f: f.read_bytes() for f in path.rglob("*") if f.is_file()}
    with pytest.raises(hevr.ParameterError, match="key"):
        hevr.encrypt_volume(vol, path, keypair512[0], brick=BRICK, progress=False, resume=True)
    assert before == {f: f.read_bytes() for f in path.rglob("*") if f.is_file()}


@pytest.mark.parametrize(
    "vol, kw, match",
    [
        (np.full(SHAPE, np.nan, np.float32), {"value_range": (0, 1)}, "NaN"),
        (np.full(SHAPE, np.inf), {"value_range": (0, 1)}, "NaN or infinity"),
        (np.zeros((0, 3, 3), np.uint8), {}, "non-empty"),
        (np.zeros((3, 3), np.uint8), {}, "3-D"),
        (np.zeros((3, 3, 3), np.complex64), {}, "dtype"),
        (np.zeros((3, 3, 3), object), {}, "dtype"),
        (np.full(SHAPE, 300, np.int16), {"value_range": (0, 255)}, "value_range"),
        (np.zeros(SHAPE, np.uint8), {"value_range": (5, 1)}, "value_range"),
        (np.zeros(SHAPE, np.uint8), {"brick": 0}, "brick"),
        (np.zeros(SHAPE, np.uint8), {"brick": (2, -1, 2)}, "brick"),
        (np.zeros(SHAPE, np.uint8), {"vector_dims": 1}, "vector_dims"),
        (np.zeros(SHAPE, np.uint8), {"scalar": False}, "channel"),
        (np.zeros(SHAPE, np.uint8), {"spacing": (1, 0, 1)}, "spacing"),
    ],
)
def test_bad_input(tmp_path, keypair256, vol, kw, match):
    with pytest.raises(hevr.HevrError, match=match):
        hevr.encrypt_volume(vol, tmp_path / "v.zarr", keypair256[0], progress=False, **kw)
    assert not (tmp_path / "v.zarr").exists()


def test_existing_store_needs_overwrite_and_is_kept(tmp_path, keypair256):
    path = tmp_path / "v.zarr"
    hevr.encrypt_volume(np.ones(SHAPE, np.uint8), path, keypair256[0], brick=BRICK, progress=False)
    digest = hashlib.sha256(b"".join(f.read_bytes() for f in sorted(path.rglob("*")) if f.is_file())).hexdigest()
    with pytest.raises(hevr.StoreExistsError, match="overwrite=True"):
        hevr.encrypt_volume(np.zeros(SHAPE, np.uint8), path, keypair256[0], brick=BRICK, progress=False)
    assert (
        digest == hashlib.sha256(b"".join(f.read_bytes() for f in sorted(path.rglob("*")) if f.is_file())).hexdigest()
    )
    ev = hevr.encrypt_volume(
        np.zeros(SHAPE, np.uint8), path, keypair256[0], brick=BRICK, progress=False, overwrite=True
    )
    assert ev.meta.complete


def test_refuses_to_delete_a_non_store(tmp_path, keypair256):
    (tmp_path / "precious").mkdir()
    (tmp_path / "precious" / "thesis.txt").write_text("do not delete")
    with pytest.raises(hevr.StoreExistsError):
        hevr.encrypt_volume(
            np.ones(SHAPE, np.uint8), tmp_path / "precious", keypair256[0], overwrite=True, progress=False
        )
    assert (tmp_path / "precious" / "thesis.txt").read_text() == "do not delete"


def test_storage_is_ciphertext_bytes_only(tmp_path, keypair256):
    pub, priv = keypair256
    vol = np.ones((4, 6, 8), np.uint8)
    ev = hevr.encrypt_volume(vol, tmp_path / "v.zarr", priv, brick=(2, 3, 4), vector_dims=4, progress=False)
    for name, k in (("scalar", 1), ("vector", 4)):
        files = [f for f in (Path(ev.path) / name / "c").rglob("*") if f.is_file()]
        size = sum(f.stat().st_size for f in files)
        cipher = vol.size * k * pub.ciphertext_bytes
        # zstd frame + block headers (a few bytes per 128 KiB) and the crc32c: nothing else
        assert len(files) == 8 and cipher <= size <= cipher + 24 * len(files)


@pytest.mark.parametrize("shape, brick", [((5, 7, 9), 4), ((33, 2, 17), (16, 2, 16)), ((1, 1, 3), 8)])
def test_edge_bricks_store_no_padding(tmp_path, keypair256, shape, brick):
    """Edge bricks are stored without their zero padding (zstd): the store holds the
    ciphertext bytes plus under 5 %, although the padded chunk grid is up to 8x larger."""
    pub, priv = keypair256
    vol = np.arange(int(np.prod(shape)), dtype=np.uint16).reshape(shape)
    ev = hevr.encrypt_volume(vol, tmp_path / "v.zarr", priv, brick=brick, vector_dims=2, progress=False)
    for name, k in (("scalar", 1), ("vector", 2)):
        size = sum(f.stat().st_size for f in (Path(ev.path) / name / "c").rglob("*") if f.is_file())
        cipher = vol.size * k * pub.ciphertext_bytes
        assert cipher <= size <= 1.05 * cipher + 24 * int(np.prod(ev.grid)), (name, size, cipher)
    ev = hevr.open_volume(ev.path, verify="full")  # every chunk size and digest checks out
    assert [priv.decrypt(c) for c in ev.read_brick((0, 0, 0))][:3] == [0, 1, 2]


def test_relative_path_is_made_absolute(tmp_path, keypair256, monkeypatch):
    monkeypatch.chdir(tmp_path)
    ev = hevr.encrypt_volume(np.ones(SHAPE, np.uint8), "rel.zarr", keypair256[0], brick=BRICK, progress=False)
    assert Path(ev.path).is_absolute() and Path(ev.path) == tmp_path / "rel.zarr"


# -- nothing lost, nothing mixed ----------------------------------------------------------------


def _tree(path: Path) -> dict:
    return {str(f.relative_to(path)): f.read_bytes() for f in sorted(path.rglob("*")) if f.is_file()}


def _interrupt_after(monkeypatch, n_bricks: int) -> None:
    real, calls = store_mod._encrypt_brick, []

    def flaky(*args, **kw):
        if len(calls) >= n_bricks:
            raise RuntimeError("worker died")
        calls.append(args[2])
        return real(*args, **kw)

    monkeypatch.setattr(store_mod, "_encrypt_brick", flaky)


def test_resume_with_another_volume_of_the_same_shape_is_refused(tmp_path, keypair256, monkeypatch):
    pub, _ = keypair256
    vol, path = _vol("uint8"), tmp_path / "v.zarr"
    _interrupt_after(monkeypatch, 5)
    with dask.config.set(scheduler="synchronous"), pytest.raises(RuntimeError, match="worker died"):
        hevr.encrypt_volume(vol, path, pub, brick=BRICK, progress=False)
    monkeypatch.undo()
    before = _tree(path)
    other = vol.copy()
    other[4, 6, 8] ^= 1  # one voxel of the last brick
    with pytest.raises(hevr.ParameterError, match=r"vol: brick \(2, 2, 2\) differs from the volume"):
        hevr.encrypt_volume(other, path, pub, brick=BRICK, progress=False, resume=True)
    with pytest.raises(hevr.ParameterError, match="differs"):  # a dask array is compared the same way
        hevr.encrypt_volume(da.from_array(other, chunks=(3, 3, 3)), path, pub, brick=BRICK, progress=False, resume=True)
    assert _tree(path) == before
    ev = hevr.encrypt_volume(da.from_array(vol, chunks=(3, 3, 3)), path, pub, brick=BRICK, progress=False, resume=True)
    assert ev.meta.complete


def test_resume_without_the_journal_is_refused(tmp_path, keypair256, monkeypatch):
    pub, _ = keypair256
    vol, path = _vol("uint8"), tmp_path / "v.zarr"
    _interrupt_after(monkeypatch, 3)
    with dask.config.set(scheduler="synchronous"), pytest.raises(RuntimeError):
        hevr.encrypt_volume(vol, path, pub, brick=BRICK, progress=False)
    monkeypatch.undo()
    with dask.config.set({"hevr.journal-dir": str(tmp_path / "elsewhere")}):
        with pytest.raises(hevr.ParameterError, match="resume: no resume journal"):
            hevr.encrypt_volume(vol, path, pub, brick=BRICK, progress=False, resume=True)


def test_journal_is_private_and_holds_no_ciphertext(tmp_path, keypair256):
    folder = tmp_path / "journals"
    with dask.config.set({"hevr.journal-dir": str(folder)}):
        ev = hevr.encrypt_volume(_vol("uint8"), tmp_path / "v.zarr", keypair256[0], brick=BRICK, progress=False)
    (journal,) = folder.iterdir()
    assert journal.name == f"{ev.meta.store_id}.json" and journal.stat().st_mode & 0o777 == 0o600
    doc = json.loads(journal.read_text())
    assert doc["store"] == ev.path and len(doc["bricks"]) == 27
    store_text = b"".join(_tree(Path(ev.path)).values())
    assert not any(d.encode() in store_text for d in doc["bricks"].values())  # plaintext digests stay home


@pytest.mark.parametrize(
    "vol, kw, match",
    [
        (np.full(SHAPE, 2**63, np.uint64), {"key_bits": 64}, "do not fit a 64-bit key"),
        (np.ones(SHAPE, np.uint8), {"vector_dims": 3, "vector_digits": 12, "value_range": (0, 1)}, None),
        (np.ones(SHAPE) * 1e80, {"value_range": (0, 2e80)}, "digits: 3 digits overflow"),
        (np.ones(SHAPE, np.uint8), {"brick": 0}, "brick"),
    ],
)
def test_overwrite_with_invalid_input_keeps_the_old_store(tmp_path, keypair256, vol, kw, match):
    pub, priv = keypair256
    path = tmp_path / "v.zarr"
    hevr.encrypt_volume(_vol("uint8"), path, pub, brick=BRICK, progress=False)
    before = _tree(path)
    kw = {"brick": BRICK, **kw}
    if "key_bits" in kw:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", hevr.InsecureKeyWarning)
            pub = hevr.generate_keypair(kw.pop("key_bits"))[0]
    if match is None:  # valid input: the overwrite goes through
        hevr.encrypt_volume(vol, path, pub, progress=False, overwrite=True, **kw)
        assert _tree(path) != before
        return
    with pytest.raises(hevr.HevrError, match=match):
        hevr.encrypt_volume(vol, path, pub, progress=False, overwrite=True, **kw)
    assert _tree(path) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["v.zarr"]


def test_overwrite_that_fails_midway_keeps_the_old_store(tmp_path, keypair256, monkeypatch):
    pub, priv = keypair256
    path = tmp_path / "v.zarr"
    hevr.encrypt_volume(_vol("uint8"), path, pub, brick=BRICK, progress=False)
    before = _tree(path)
    _interrupt_after(monkeypatch, 4)
    with dask.config.set(scheduler="synchronous"), pytest.raises(RuntimeError, match="worker died"):
        hevr.encrypt_volume(np.zeros(SHAPE, np.uint8), path, pub, brick=BRICK, progress=False, overwrite=True)
    assert _tree(path) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["v.zarr"]  # the partial new store is gone
    monkeypatch.undo()
    ev = hevr.encrypt_volume(np.zeros(SHAPE, np.uint8), path, pub, brick=BRICK, progress=False, overwrite=True)
    assert np.array_equal(_decrypt_scalar(ev, priv).astype(np.int64), np.zeros(SHAPE, np.int64))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["v.zarr"]  # the old store is deleted after the swap


def test_remote_store_overwrite_swaps(keypair256):
    """fsspec stores (memory://) get the same write-beside-then-swap."""
    pub, priv = keypair256
    url = "memory://hevr-test-overwrite/v.zarr"
    hevr.encrypt_volume(np.ones(SHAPE, np.uint8), url, pub, brick=BRICK, progress=False)
    ev = hevr.encrypt_volume(np.full(SHAPE, 7, np.uint8), url, pub, brick=BRICK, progress=False, overwrite=True)
    assert np.array_equal(_decrypt_scalar(ev, priv).astype(np.int64), np.full(SHAPE, 7))


# -- paths that hold something else, remote paths, graph names (review findings) -----------------


def test_a_remote_prefix_with_other_data_is_never_written_over(keypair256):
    fs = fsspec.filesystem("memory")
    fs.pipe("/hevr-test-precious/notes.txt", b"do not delete")
    url = "memory://hevr-test-precious"
    with pytest.raises(hevr.StoreExistsError, match="already exists"):
        hevr.encrypt_volume(np.ones(SHAPE, np.uint8), url, keypair256[0], brick=BRICK, progress=False)
    with pytest.raises(hevr.StoreExistsError, match="not an hevr store"):
        hevr.encrypt_volume(np.ones(SHAPE, np.uint8), url, keypair256[0], brick=BRICK, progress=False, overwrite=True)
    assert fs.cat("/hevr-test-precious/notes.txt") == b"do not delete"


def test_overwrite_refuses_a_zarr_group_that_is_not_hevr(tmp_path, keypair256):
    group = zarr.open_group(str(tmp_path / "other.zarr"), mode="w")
    group.create_array("precious", shape=(2,), dtype="uint8")
    with pytest.raises(hevr.StoreExistsError, match="not an hevr store"):
        hevr.encrypt_volume(
            np.ones(SHAPE, np.uint8),
            tmp_path / "other.zarr",
            keypair256[0],
            brick=BRICK,
            progress=False,
            overwrite=True,
        )
    assert "precious" in zarr.open_group(str(tmp_path / "other.zarr"), mode="r")


def test_remote_url_with_a_trailing_slash_is_one_store(keypair256):
    pub, priv = keypair256
    vol = _vol("uint8")
    ev = hevr.encrypt_volume(vol, "memory://hevr-test-slash/v.zarr/", pub, brick=BRICK, progress=False)
    assert ev.path == "memory://hevr-test-slash/v.zarr"
    assert np.array_equal(_decrypt_scalar(ev, priv).astype(np.int64), vol.astype(np.int64))
    again = hevr.encrypt_volume(vol, "memory://hevr-test-slash/v.zarr/", pub, brick=BRICK, progress=False, resume=True)
    assert again.meta.store_id == ev.meta.store_id


def test_the_task_graph_names_nothing_derived_from_the_volume(tmp_path, keypair256, monkeypatch):
    """dask's default name for an in-memory array is a hash of its content, which would let
    anyone who sees the graph (scheduler logs, dashboard) confirm a guessed volume."""
    vol = _vol("uint8")
    seen = []
    real = store_mod.compute

    def spy(tasks, **kw):
        seen.extend(str(k) for t in tasks for k in dict(t.__dask_graph__()).keys())
        return real(tasks, **kw)

    monkeypatch.setattr(store_mod, "compute", spy)
    hevr.encrypt_volume(vol, tmp_path / "v.zarr", keypair256[0], brick=BRICK, progress=False)
    token = dask.base.tokenize(vol)
    assert seen and not any(token in k for k in seen)
    assert any(k.startswith("hevr-plain-") or "hevr-plain-" in k for k in seen)


def test_an_interrupted_swap_is_named(tmp_path, keypair256):
    """Killed between the two renames of an overwrite: nothing at the path, both stores beside it."""
    ev = hevr.encrypt_volume(_vol("uint8"), tmp_path / "v.zarr", keypair256[0], brick=BRICK, progress=False)
    Path(ev.path).rename(tmp_path / ".v.zarr.hevr-old-0123abcd")
    with pytest.raises(hevr.MissingFileError, match=r"interrupted overwrite left \.v\.zarr\.hevr-old-0123abcd"):
        hevr.open_volume(tmp_path / "v.zarr")
    (tmp_path / ".v.zarr.hevr-old-0123abcd").rename(tmp_path / "v.zarr")
    hevr.open_volume(tmp_path / "v.zarr")


def test_overwrite_deletes_the_replaced_stores_journal(tmp_path, keypair256):
    folder = tmp_path / "journals"
    with dask.config.set({"hevr.journal-dir": str(folder)}):
        first = hevr.encrypt_volume(_vol("uint8"), tmp_path / "v.zarr", keypair256[0], brick=BRICK, progress=False)
        second = hevr.encrypt_volume(
            _vol("uint8"), tmp_path / "v.zarr", keypair256[0], brick=BRICK, progress=False, overwrite=True
        )
    assert sorted(p.name for p in folder.iterdir()) == [f"{second.meta.store_id}.json"]
    assert first.meta.store_id != second.meta.store_id


def test_an_unusable_backend_is_refused_before_the_disk_is_touched(tmp_path, keypair256, monkeypatch):
    """backend="cuda" without CuPy failed only after the store and its journal existed; the docs
    promise inputs are checked first."""
    from hevr import backends

    monkeypatch.setitem(__import__("sys").modules, "cupy", None)  # CuPy not installed (import raises)
    monkeypatch.delitem(backends._INSTANCES, "cuda", raising=False)
    folder = tmp_path / "journals"
    with (
        dask.config.set({"hevr.journal-dir": str(folder)}),
        pytest.raises(hevr.MissingDependencyError, match="backend: 'cuda' needs CuPy"),
    ):
        hevr.encrypt_volume(
            _vol("uint8"), tmp_path / "v.zarr", keypair256[0], brick=BRICK, progress=False, backend="cuda"
        )
    assert not (tmp_path / "v.zarr").exists()
    assert not folder.exists() or not any(folder.iterdir())
