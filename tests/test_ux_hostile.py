"""Hostile tests (review of issue 17) of ``.hevrsums`` (keep_sums / load_sums / recolour), ``render(compute=False)``,
the progress display, the Viewer and the ``hevr render --keep-sums`` / ``hevr recolour`` CLI.

The tests marked "BUG" fail on the code as reviewed; the others pin down behaviour that had no test.
256-bit keys and tiny phantoms: fast, NOT secure.
"""

from __future__ import annotations

import hashlib
import json
import struct
import time

import dask
import numpy as np
import pytest

import hevr
from hevr.cli.main import main
from hevr.rendering import view as view_mod
from hevr.rendering.pipeline import cache as render_cache
from hevr.rendering.pipeline import sums_file
from hevr.runtime import progress as _progress
from hevr.runtime import scheduler as _dask

pytestmark = pytest.mark.filterwarnings("ignore::hevr.InsecureKeyWarning")

NODES = [(0.2, "red"), (0.8, "blue")]


@pytest.fixture(scope="module")
def stores(tmp_path_factory, keypair256):
    pub, priv = keypair256
    d = tmp_path_factory.mktemp("review17")
    both = hevr.encrypt_volume(hevr.phantom(8), d / "both.zarr", priv, brick=4, vector_dims=4, progress=False)
    fvol = (np.random.default_rng(1).random((8, 8, 8)) * 7 - 3).astype(np.float32)
    flt = hevr.encrypt_volume(
        fvol, d / "float.zarr", priv, brick=4, vector_dims=3, value_range=(-3, 4.5), progress=False
    )
    vonly = hevr.encrypt_volume(
        hevr.phantom(8), d / "vonly.zarr", priv, brick=4, vector_dims=2, scalar=False, progress=False
    )
    return {"both": both, "float": flt, "vonly": vonly, "dir": d}


def _same(a: hevr.EncryptedImage, b: hevr.EncryptedImage) -> bool:
    return (
        a.shape[:2] == b.shape[:2]
        and a.exponent == b.exponent
        and a.offset == b.offset
        and a.per_pack == b.per_pack
        and len(a.ciphertexts) == len(b.ciphertexts)
        and all(np.array_equal(x, y) for x, y in zip(a.ciphertexts, b.ciphertexts))
    )


def _sums_file(ev, cam, path, **kw):
    hevr.clear_cache()
    hevr.render(ev, cam, keep_sums=path, cache=False, progress=False, **kw)
    blob = path.read_bytes()
    (hl,) = struct.unpack_from("<I", blob, 9)
    return json.loads(blob[13 : 13 + hl]), blob[13 + hl : -32]


def _write(path, head, body):
    """A .hevrsums file with a crafted header and a VALID SHA-256 trailer (anyone can compute it)."""
    raw = json.dumps(head).encode()
    data = sums_file.MAGIC + struct.pack("<I", len(raw)) + raw + body
    path.write_bytes(data + hashlib.sha256(data).digest())


# -- pinned behaviour: recolour is bit for bit a full render --------------------------------------------------
CASES = [
    # store, camera, sampling, step, tile, pack, precision, comb_digits, digits
    ("both", "parallel", "trilinear", 0.37, 3, False, 0, 1, 5),
    ("float", "inside", "nearest", 2.5, 1, True, 7, 12, 3),
    ("vonly", "wide", "trilinear", 1.0, 5, True, 4, 2, 9),
]


def _camera(kind, ev):
    if kind == "parallel":
        return hevr.Camera.orbit(ev, azimuth=40, elevation=-10, width=8, height=6, parallel=True)
    if kind == "inside":  # the eye inside the volume
        return hevr.Camera((3.5, 3.2, 3.7), (0, 0, 0), width=7, height=5, view_angle=90)
    return hevr.Camera((3.5, 3.5, 30), (3.5, 3.5, 0), width=20, height=20, view_angle=60)  # tiles that miss


@pytest.mark.parametrize("case", CASES, ids=[c[0] + "-" + c[1] for c in CASES])
def test_recolour_is_bit_identical_across_modes_and_parameters(stores, tmp_path, case):
    """Pins recolour == render for pack=False, odd tiles, step != 1, non-default precision and
    comb_digits, trilinear digits, parallel / inside / mostly-missing cameras, a float volume
    with value_range and a vector-only 2-dim store (none of which had a test)."""
    name, camkind, sampling, step, tile, pack, precision, comb, digits = case
    ev = stores[name]
    cam = _camera(camkind, ev)
    path = tmp_path / "v.hevrsums"
    common = dict(
        sampling=sampling, step=step, tile=tile, pack=pack, precision=precision, comb_digits=comb, digits=digits
    )
    hevr.clear_cache()
    hevr.render(ev, cam, mode="tf", nodes=NODES, keep_sums=path, cache=False, progress=False, **common)
    for mode, kw in [
        ("tf", {"nodes": [(0.0, "lime"), (0.5, "#ff0"), (1.0, "white")]}),
        ("emphasize", {"density": 0.4}),
    ]:
        again = hevr.recolour(path, mode=mode, precision=precision, comb_digits=comb, pack=pack, progress=False, **kw)
        full = hevr.render(ev, cam, mode=mode, cache=False, progress=False, **common, **kw)
        assert again.stats["map_tasks"] == 0
        assert _same(again, full) and again.info == full.info and np.array_equal(again.hits, full.hits)


# -- pinned behaviour: compute=False ----------------------------------------------------------------------
def test_deferred_render_from_cached_sums_and_resident_bricks(stores):
    """Pins compute=False with cached sums (map_tasks 0, no new cache entry) and with a resident volume
    on the default scheduler: the Delayed computes to the full render's ciphertexts."""
    ev = stores["both"]
    cam = hevr.Camera.orbit(ev, azimuth=25, elevation=15, width=9, height=7)
    full = hevr.render(ev, cam, mode="tf", nodes=NODES, cache=False, progress=False)
    hevr.clear_cache()
    d = hevr.render(ev, cam, mode="tf", nodes=NODES, compute=False)
    assert len(render_cache._CACHE) == 0 and _same(d.compute(), full)
    hevr.render(ev, cam, mode="emphasize", density=0.3, progress=False)  # caches the vector sums
    d = hevr.render(ev, cam, mode="tf", nodes=NODES, compute=False)
    img = d.compute(scheduler="sync")
    assert _same(img, full) and img.stats["map_tasks"] == 0 and len(render_cache._CACHE) == 1
    d = hevr.render(ev.persist(), cam, mode="tf", nodes=NODES, compute=False, cache=False)
    img = d.compute()
    assert _same(img, full) and img.stats["resident"] is True


# -- BUG: hostile .hevrsums headers -------------------------------------------------------------------------
def test_load_sums_refuses_a_camera_bigger_than_any_image(stores, tmp_path):
    """BUG (sums.py load_sums ~l.206): the camera's pixel count is never capped, and _read_tiles
    calls layout.pixels(i) (an int64 array of the whole tile) for every listed tile just to bound R.
    A 200 KB file with a 520192² camera, tile 4096 and 16129 tiles of -1 loads in ~350 s (measured),
    and is returned as valid. Expected: CorruptStoreError (camera larger than MAX_IMAGE_PIXELS) at once."""
    ev = stores["both"]
    head, _ = _sums_file(ev, hevr.Camera.orbit(ev, width=9, height=7), tmp_path / "a.hevrsums")
    side, tile = 16384, 4096  # 268 M pixels, 4x the image cap; 16 tiles
    head = dict(
        head,
        camera=dict(head["camera"], width=side, height=side),
        tile=tile,
        tiles=[[i, -1] for i in range((side // tile) ** 2)],
    )
    _write(tmp_path / "b.hevrsums", head, b"")
    t0 = time.perf_counter()
    with pytest.raises(hevr.CorruptStoreError, match="camera"):
        hevr.load_sums(tmp_path / "b.hevrsums")
    assert time.perf_counter() - t0 < 0.2


def test_load_sums_huge_integer_step_is_checked_by_the_renders_rule(stores, tmp_path):
    """Was a BUG (sums.py load_sums, the 'step' check): np.isfinite(10**30) raised TypeError (a Python
    int beyond int64) and the loader crashed. Now the loader applies the render's own check_step:
    10**30 is a valid (if useless) step, and a step the render refuses is named."""
    ev = stores["both"]
    head, body = _sums_file(ev, hevr.Camera.orbit(ev, width=9, height=7), tmp_path / "a.hevrsums")
    _write(tmp_path / "b.hevrsums", dict(head, step=10**30), body)
    assert hevr.load_sums(tmp_path / "b.hevrsums").step == 1e30
    for bad in (0, -1.5, "1", None, [1]):
        _write(tmp_path / "c.hevrsums", dict(head, step=bad), body)
        with pytest.raises(hevr.CorruptStoreError, match="'step'"):
            hevr.load_sums(tmp_path / "c.hevrsums")


def test_load_sums_refuses_weight_digits_with_nearest_sampling(stores, tmp_path):
    """BUG (sums.py load_sums, 'weight_digits'): docs/sums-format.md says 0 for nearest, but any
    [0, 9] is accepted; recolour then trips its 'pragma: no cover' branch and raises a bare
    HevrError ('sums: expected weights of 0 digits, got 3') instead of the loader's CorruptStoreError."""
    ev = stores["both"]
    head, body = _sums_file(
        ev,
        hevr.Camera.orbit(ev, width=9, height=7),
        tmp_path / "a.hevrsums",
        mode="tf",
        nodes=NODES,
        sampling="nearest",
    )
    assert head["sampling"] == "nearest" and head["weight_digits"] == 0
    _write(tmp_path / "b.hevrsums", dict(head, weight_digits=3), body)
    with pytest.raises(hevr.CorruptStoreError, match="'weight_digits'"):
        hevr.load_sums(tmp_path / "b.hevrsums")


# -- BUG: keep_sums is checked only after the whole render ------------------------------------------------
def test_keep_sums_path_is_checked_before_any_map_task(stores, tmp_path, monkeypatch):
    """BUG (encrypted.py render, keep_sums): a keep_sums in a missing folder, a folder, '' or a
    non-path is only noticed by save_sums after the map step ran (minutes at 2048 bits), and comes
    out as FileNotFoundError / IsADirectoryError / ValueError / TypeError. Expected: a ParameterError
    naming keep_sums before any task (as the CLI's check_output_file does)."""
    ev = stores["both"]
    cam = hevr.Camera.orbit(ev, width=9, height=7)

    def no_tasks(*a, **k):
        raise AssertionError("the render ran before keep_sums was checked")

    monkeypatch.setattr(view_mod, "run_tasks", no_tasks)
    for bad in (tmp_path / "missing" / "v.hevrsums", tmp_path, "", 123):
        hevr.clear_cache()
        with pytest.raises((hevr.ParameterError, hevr.MissingFileError), match="keep_sums"):
            hevr.render(ev, cam, keep_sums=bad, progress=False)


# -- BUG: CLI outputs that overwrite each other -----------------------------------------------------------
def test_cli_keep_sums_same_path_as_out_is_refused(stores, tmp_path, capsys):
    """BUG (cli/render.py cmd_render): 'hevr render STORE --out F --keep-sums F' writes the sums,
    then img.save(F) replaces them; exit 0 and it prints 'wrote F: the view's encrypted ray sums'
    although F is now a frame. Expected: exit 2, '--keep-sums: ...' (same for recolour --out SUMS,
    which silently replaces the sums it read)."""
    f = tmp_path / "same.hevr"
    code = main(
        [
            "render",
            str(stores["both"].path),
            "--out",
            str(f),
            "--keep-sums",
            str(f),
            "--size",
            "6x5",
            "--tf",
            "0.3:red",
            "-q",
        ]
    )
    err = capsys.readouterr().err
    assert code == 2 and "--keep-sums" in err
    sums = tmp_path / "s.hevrsums"
    assert (
        main(
            [
                "render",
                str(stores["both"].path),
                "--out",
                str(tmp_path / "a.hevr"),
                "--keep-sums",
                str(sums),
                "--size",
                "6x5",
                "--tf",
                "0.3:red",
                "-q",
            ]
        )
        == 0
    )
    before = sums.read_bytes()
    code = main(["recolour", str(sums), "--out", str(sums), "--tf", "0.6:blue", "-q"])
    capsys.readouterr()
    assert code == 2 and sums.read_bytes() == before


# -- BUG: distributed progress of a failed job -------------------------------------------------------------
def test_failed_distributed_job_does_not_end_as_success(cluster, monkeypatch):
    """BUG (_dask.py compute, distributed branch): as_completed yields errored futures too, so the bar
    reaches total and Progress.close() styles the Jupyter widget 'success' (green, 2/2) although the
    job raised. The local scheduler ends it 'warning'. Expected: not 'success' on failure."""
    pytest.importorskip("ipywidgets")
    shown = []
    monkeypatch.setattr(_progress, "_in_jupyter", lambda: True)
    monkeypatch.setattr("IPython.display.display", lambda w: shown.append(w))

    def boom(i):
        raise RuntimeError("task failed")

    with pytest.raises(RuntimeError, match="task failed"):
        _dask.compute([dask.delayed(boom)(1), dask.delayed(int)(2)], client=cluster, desc="bad")
    (box,) = shown
    assert box.children[0].bar_style != "success"


# -- Viewer ----------------------------------------------------------------------------------------------
def test_viewer_remove_buttons_after_a_middle_removal(stores, keypair256):
    """Pins the TF editor: after removing a middle row, the remaining rows' buttons still remove their
    own row; the last node cannot be removed (status says so, no exception)."""
    hevr.clear_cache()
    v = hevr.Viewer(
        stores["both"],
        keypair256[1],
        width=6,
        height=5,
        mode="tf",
        nodes=[(0.1, "red"), (0.3, "lime"), (0.5, "blue"), (0.7, "white")],
    )
    rows = list(v.node_rows)
    rows[1][2].click()
    assert [d for d, _ in v.nodes()] == [0.1, 0.5, 0.7]
    rows[3][2].click()
    assert [d for d, _ in v.nodes()] == [0.1, 0.5]
    assert v.history[-1]["map_tasks"] == 0  # re-coloured from cached sums
    rows[0][2].click()
    rows[2][2].click()
    assert [d for d, _ in v.nodes()] == [0.5] and "at least one node" in v.status.value


def test_viewer_opens_on_a_vector_only_store_with_defaults(stores, keypair256):
    """BUG (viewer.py Viewer.__init__): mode defaults to 'xray', so Viewer(ev, key) on a store encrypted
    with --no-scalar raises ParameterError although the store offers 'emphasize'/'tf'. Expected: the
    default mode is the first one the store has."""
    v = hevr.Viewer(stores["vonly"], keypair256[1], width=6, height=5)
    assert v.mode.value in ("emphasize", "tf") and "error_message" not in v.history[-1]
