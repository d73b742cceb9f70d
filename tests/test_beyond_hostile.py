"""Hostile review of the pyramid, slices and gradient features (issue 15).

The tests marked "BUG" fail on the code as reviewed, each because of a real defect (the docstring
says which); the others pin important behaviour that no other test covered. 256-bit keys and
tiny volumes: fast, NOT secure.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

import hevr
from hevr.errors import HevrError
from hevr.store.pyramid import build_pyramid
from hevr.volume.gradient import gradient_encoding

pytestmark = pytest.mark.filterwarnings("ignore::hevr.InsecureKeyWarning")


def _render_ok(ev, vol, priv, cam, **kw):
    got = hevr.render(ev, cam, progress=False, **kw).decrypt(priv)
    ref = hevr.render_plain(vol, cam, spacing=ev.spacing, value_range=ev.value_range, vector_dims=ev.vector_dims, **kw)
    return bool((np.abs(got - ref) <= hevr.error_bound(ev, cam, **kw)).all())


# -- bugs -------------------------------------------------------------------------------------------
def test_resume_of_a_finished_store_keeps_its_pyramid(tmp_path, keypair256):
    """BUG (writer.py:341/400): ``encrypt_volume(..., resume=True)`` on a finished store — documented as a
    verified no-op (hevr/store/journal.py) — rewrites the ``hevr`` attribute from a fresh metadata object
    without ``levels`` but leaves the ``ome`` attribute: the store no longer opens ("the group's zarr.json
    has unexpected content"). ``hevr encrypt --resume`` does the same. Level 0 is lost for a no-op."""
    _, priv = keypair256
    vol, path = hevr.phantom(8), tmp_path / "v.zarr"
    hevr.encrypt_volume(vol, path, priv, brick=4, progress=False)
    build_pyramid(path, 1, progress=False)
    hevr.encrypt_volume(vol, path, priv, brick=4, resume=True, progress=False)  # nothing to do
    ev = hevr.open_volume(path)
    assert ev.levels == 1
    assert _render_ok(ev, vol, priv, hevr.Camera.orbit(ev, width=6, height=6), level=1)


def test_a_stale_handle_cannot_clobber_a_replaced_store(tmp_path, keypair256):
    """BUG (pyramid.py:167, _start_level/_write_meta): ``build_pyramid`` trusts the metadata of the handle
    it is given. With a handle opened before the store was replaced (``overwrite=True``), it writes the OLD
    store's ``hevr`` attribute (old store_id and array digests) over the new store before its first task
    fails: every brick of the new store then fails its digest — a server-side, keyless call destroyed a
    good store. It must re-read the store (and refuse a changed store_id) before writing anything."""
    _, priv = keypair256
    path = tmp_path / "v.zarr"
    vol = hevr.phantom(8)
    stale = hevr.encrypt_volume(vol, path, priv, brick=4, progress=False)
    vol2 = (vol // 2).astype(np.uint8)
    hevr.encrypt_volume(vol2, path, priv, brick=4, overwrite=True, progress=False)
    try:
        build_pyramid(stale, 1, progress=False)
    except HevrError:
        pass  # refusing is fine; corrupting the new store is not
    ev = hevr.open_volume(path)
    assert _render_ok(ev, vol2, priv, hevr.Camera.orbit(ev, width=6, height=6))


def test_thick_slab_nearest_ties_match_the_reference(tmp_path, keypair256):
    """BUG (plane.py:254 + rays.py:210, sample_positions): a slab sample of the encrypted slice sits at
    ``(centre − (S−1)/2·h·n) + (k0 + k)·h·n`` while render_slice_plain (the documented definition) uses
    ``centre + (k − (S−1)/2)·h·n``. At an exact half-voxel position (round half up) the two round
    differently, so ``render_slice`` picks the neighbouring voxel: errors of whole data values (231 here),
    far beyond ``error_bound`` (0.013), on ordinary thick slabs with anisotropic spacing."""
    _, priv = keypair256
    vol = np.random.default_rng(0).integers(0, 256, (6, 7, 8)).astype(np.uint8)
    for sp, make in [
        ((1.0, 0.1, 0.1), lambda s: hevr.Plane.coronal((6, 7, 8), 0.5, spacing=s, slab=6, slab_step=1.0)),
        ((2.0, 0.1, 0.3), lambda s: hevr.Plane.axial((6, 7, 8), 4, spacing=s, slab=6, slab_step=0.7)),
    ]:
        ev = hevr.encrypt_volume(vol, tmp_path / f"{sp[2]}.zarr", priv, brick=4, spacing=sp, progress=False)
        plane = make(sp)
        got = hevr.render_slice(ev, plane, progress=False).decrypt(priv)
        ref = hevr.render_slice_plain(vol, plane, spacing=sp)
        assert (np.abs(got - ref) <= hevr.error_bound(ev, plane)).all(), float(np.abs(got - ref).max())


def test_a_tiny_pixel_spacing_is_a_parameter_error(tmp_path, capsys, keypair256):
    """BUG (plane.py:398-399, 417-419): ``Plane.axial/coronal/sagittal/oblique`` with a pixel spacing (or a
    voxel spacing) whose extent/spacing overflows to inf raise a bare OverflowError ("cannot convert float
    infinity to integer"); ``hevr slice --pixel-spacing 1e-320`` therefore exits 1 ("the data failed") with
    a message that does not start with the option, instead of exit 2 naming --pixel-spacing."""
    with pytest.raises(hevr.ParameterError, match="pixel_spacing"):
        hevr.Plane.axial((8, 8, 8), 2, pixel_spacing=1e-320)
    with pytest.raises(hevr.ParameterError, match="pixel_spacing"):
        hevr.Plane.oblique((8, 8, 8), pixel_spacing=5e-324)
    from hevr.cli.main import main

    path = tmp_path / "v.zarr"
    hevr.encrypt_volume(hevr.phantom(8), path, keypair256[0], brick=4, progress=False)
    code = main(
        ["slice", str(path), "--out", str(tmp_path / "s.hevr"), "--axial", "2", "--pixel-spacing", "1e-320", "-q"]
    )
    err = capsys.readouterr().err
    assert code == 2 and "--pixel-spacing" in err, (code, err)


def test_recolour_of_level_sums_keeps_the_level(tmp_path, keypair256):
    """BUG (sums.py:152 and :351): the ``.hevrsums`` header does not record the pyramid level and
    ``recolour`` builds the image without ``level=``: the re-coloured frame of a level-1 view says nothing
    about the level, while its recorded camera and step are the level frame's (camera moved by −origin,
    step doubled) — its provenance describes a view nobody rendered."""
    _, priv = keypair256
    ev = hevr.encrypt_volume(hevr.phantom(8), tmp_path / "v.zarr", priv, brick=4, vector_dims=3, progress=False)
    ev = build_pyramid(ev, 1, progress=False)
    cam = hevr.Camera.orbit(ev, width=6, height=6)
    a = hevr.render(
        ev, cam, mode="tf", nodes=[(0.3, "red")], level=1, keep_sums=tmp_path / "l1.hevrsums", progress=False
    )
    b = hevr.recolour(tmp_path / "l1.hevrsums", mode="tf", nodes=[(0.3, "red")], progress=False)
    assert [c.tobytes() for c in a.ciphertexts] == [c.tobytes() for c in b.ciphertexts]
    assert a.info.get("level") == 1
    assert b.info.get("level") == 1


def test_rebuilding_a_level_whose_arrays_vanished_is_a_store_error(tmp_path, keypair256):
    """BUG (pyramid.py:124/180): an interrupted level whose ``levels/L`` folder is gone (``hevr info`` says
    "INCOMPLETE (run hevr pyramid again to finish it)") makes the next build die with a bare
    ``KeyError: 'levels/1/done'`` (CLI: "hevr: error: KeyError: ..."); it should recreate the level's arrays
    (it holds no finished bricks) or raise a StoreError that says what is wrong."""
    pub, _ = keypair256
    path = tmp_path / "v.zarr"
    hevr.encrypt_volume(hevr.phantom(8), path, pub, brick=4, progress=False)
    import hevr.store.pyramid as pyr

    real = pyr._level_brick
    pyr._level_brick = lambda *a: (_ for _ in ()).throw(RuntimeError("worker lost"))
    try:
        with pytest.raises(RuntimeError):
            build_pyramid(path, 1, progress=False)
    finally:
        pyr._level_brick = real
    shutil.rmtree(Path(path) / "levels")
    try:
        ev = build_pyramid(path, 1, progress=False)
    except HevrError:
        return
    assert ev.levels == 1


# -- pinned behaviour -------------------------------------------------------------------------------
def test_level_integrity_against_foreign_and_swapped_bricks(tmp_path, keypair256):
    """A level copied from another store of the same key and volume, or a level-2 brick (with its
    marker) put into level 1, is refused at that level; level 0 still renders correctly."""
    _, priv = keypair256
    vol = hevr.phantom(12)
    a = build_pyramid(hevr.encrypt_volume(vol, tmp_path / "a.zarr", priv, brick=4, progress=False), 2, progress=False)
    build_pyramid(hevr.encrypt_volume(vol, tmp_path / "b.zarr", priv, brick=4, progress=False), 2, progress=False)
    cam = hevr.Camera.orbit(a, azimuth=30, elevation=20, width=6, height=6)
    c = tmp_path / "c.zarr"
    shutil.copytree(a.path, c)
    shutil.rmtree(c / "levels" / "1")
    shutil.copytree(tmp_path / "b.zarr" / "levels" / "1", c / "levels" / "1")
    with pytest.raises(hevr.CorruptStoreError, match="level 1: digest mismatch"):
        hevr.render(hevr.open_volume(c), cam, level=1, progress=False)
    assert _render_ok(hevr.open_volume(c), vol, priv, cam) and _render_ok(hevr.open_volume(c), vol, priv, cam, level=2)
    shutil.rmtree(c)
    shutil.copytree(a.path, c)
    for sub in ("scalar/c/0/0/0/0", "done/c/0/0/0/0/0"):
        (c / "levels" / "1" / sub).write_bytes((c / "levels" / "2" / sub).read_bytes())
    with pytest.raises(hevr.CorruptStoreError, match="digest mismatch"):
        hevr.render(hevr.open_volume(c), cam, level=1, progress=False)


def test_level_renders_from_inside_the_volume_with_odd_steps(tmp_path, keypair256):
    """Cameras inside an anisotropic odd-shaped volume, steps other than 1, both samplings, levels 1-2:
    within error_bound of render_plain(level=)."""
    _, priv = keypair256
    vol = np.random.default_rng(3).integers(0, 256, (9, 7, 11)).astype(np.uint8)
    sp = (0.7, 1.3, 2.1)
    ev = hevr.encrypt_volume(vol, tmp_path / "v.zarr", priv, brick=4, vector_dims=3, spacing=sp, progress=False)
    ev = build_pyramid(ev, 2, progress=False)
    centre = np.array([10 * 0.7, 6 * 1.3, 8 * 2.1]) / 2
    cam = hevr.Camera(
        position=tuple(centre),
        focal_point=tuple(centre + [1, 0.3, 0.2]),
        view_up=(0, 0, 1),
        width=7,
        height=6,
        view_angle=80,
    )
    for level, step, sampling in ((1, 0.37, "trilinear"), (2, 2.3, "nearest"), (1, 1.0, "nearest")):
        assert _render_ok(ev, vol, priv, cam, level=level, step=step, sampling=sampling)
        assert _render_ok(ev, vol, priv, cam, level=level, step=step, sampling=sampling, mode="emphasize", density=0.4)


def test_gradient_of_a_memmap_in_one_voxel_bricks_is_the_whole_array_definition(tmp_path, keypair256):
    """Halos across bricks of one voxel, an axis of 2 voxels, a memmap input, anisotropic spacing: the
    stored gradient channel is exactly the quantised whole-volume g·e(d)."""
    _, priv = keypair256
    vol = (np.random.default_rng(5).random((5, 2, 7)) * 100).astype(np.float32)
    np.save(tmp_path / "m.npy", vol)
    mm = np.load(tmp_path / "m.npy", mmap_mode="r")
    sp, vr = (0.3, 1.7, 2.2), (0.0, 101.0)
    ev = hevr.encrypt_volume(
        mm,
        tmp_path / "g.zarr",
        priv,
        brick=(1, 1, 3),
        scalar=False,
        vector_dims=3,
        gradient=True,
        spacing=sp,
        value_range=vr,
        progress=False,
    )
    got = np.zeros(ev.shape + (3,))
    for idx in ev.brick_indices():
        for j, batch in enumerate(ev.read_brick(idx, "gradient")):
            got[ev.brick_slices(idx) + (j,)] = np.array([priv.decrypt(c) for c in batch]).reshape(ev.brick_shape(idx))
    assert np.array_equal(got, np.rint(gradient_encoding(vol, sp, vr, 3) * 1000))
