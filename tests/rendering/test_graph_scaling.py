"""Graph size: linear in bricks + tiles (task counts, not time); footprints bounded; client work O(B + P)."""

from __future__ import annotations

import math
import tracemalloc

import numpy as np
import pytest

import hevr
from hevr.image.tiles import TileLayout
from hevr.rendering.geometry.footprint import Footprint, brick_footprints
from hevr.rendering.geometry.rays import cast_rays
from hevr.rendering.pipeline.graph import FAN_IN, build_sums_graph

SHAPE = (8, 8, 16)
SPACING = (1.0, 0.8, 1.3)
# Each brick shape splits one axis of the one before in two: 8, 16, 32, 64, 128 bricks.
BRICKS = [(4, 4, 8), (4, 4, 4), (4, 2, 4), (2, 2, 4), (2, 2, 2)]
IMAGES = [(8, 8), (16, 12), (32, 32), (64, 48)]


@pytest.fixture(scope="module")
def family(tmp_path_factory, keypair256):
    vol = np.random.default_rng(21).integers(0, 256, SHAPE).astype(np.uint8)
    root = tmp_path_factory.mktemp("scaling")
    return [
        hevr.encrypt_volume(vol, root / f"b{i}.zarr", keypair256[1], brick=b, spacing=SPACING, progress=False)
        for i, b in enumerate(BRICKS)
    ]


def _graph(ev, cam, tile, sampling="trilinear", resident=None):
    rays = cast_rays(cam, ev.shape, ev.spacing, 1.0)
    n_tiles = TileLayout(cam.width, cam.height, tile).n_tiles
    g = build_sums_graph(ev, cam, rays, sampling, 1.0, 3, "scalar", tile, n_tiles, resident=resident)
    return g, rays, n_tiles


def _kinds(dsk: dict) -> dict[str, list]:
    out: dict[str, list] = {"map": [], "part": [], "merge": []}
    for key in dsk:
        out[str(key).split("-")[1]].append(key)
    return out


def _tree_merges(leaves: int) -> int:
    """Merge tasks of the level-by-level fan-in tree over ``leaves`` partials of one tile."""
    return -(-(leaves - 1) // (FAN_IN - 1)) if leaves > 1 else 0  # each merge removes FAN_IN - 1 but the last


def _levels(leaves: int) -> int:
    return math.ceil(math.log(leaves, FAN_IN) - 1e-12) if leaves > 1 else 0


@pytest.mark.parametrize("parallel", [False, True], ids=["perspective", "parallel"])
@pytest.mark.parametrize("tile", [4, 8])
def test_task_count_is_linear_in_bricks_tiles_and_edges(family, parallel, tile):
    for width, height in IMAGES:
        previous, previous_size = None, 0
        for ev in family:
            cam = hevr.Camera.orbit(ev, azimuth=30, elevation=20, width=width, height=height, parallel=parallel)
            g, rays, n_tiles = _graph(ev, cam, tile)
            dsk = dict(g.dsk)
            kinds = _kinds(dsk)
            assert len(dsk) == sum(len(v) for v in kinds.values())
            prints = brick_footprints(cam, ev.shape, ev.spacing, ev.brick, rays.n_samples > 0, tile)
            leaves = [sum(t in fp.tiles for fp in prints.values()) for t in range(n_tiles)]
            # selection tasks only for tiles that a single brick reaches; merges select their own
            assert len(kinds["map"]) == g.map_tasks and len(kinds["part"]) == sum(n == 1 for n in leaves)
            assert g.map_tasks == len(prints) <= math.prod(ev.grid)
            assert g.edges == sum(len(fp.tiles) for fp in prints.values())
            assert g.edges <= g.map_tasks * max(len(fp.tiles) for fp in prints.values())
            assert len(kinds["merge"]) == sum(_tree_merges(n) for n in leaves)
            # linear: map tasks, a selection per single-brick tile, at most edges/(FAN_IN - 1) + tiles merges
            assert len(kinds["merge"]) <= g.edges / (FAN_IN - 1) + n_tiles
            assert len(dsk) <= g.map_tasks + g.edges / (FAN_IN - 1) + 2 * n_tiles
            assert sum(1 for t in g.merged.values() if t is not None) == sum(n > 0 for n in leaves)
            if previous is not None:  # twice the bricks: at most twice the tasks (plus a tree level per tile)
                assert g.map_tasks <= 2 * previous.map_tasks and g.edges <= 2 * previous.edges
                assert len(dsk) <= 2 * previous_size + n_tiles
            previous, previous_size = g, len(dsk)


def test_documented_merge_bound(tmp_path, keypair256):
    """SumsGraph: 'fewer than edges/(FAN_IN - 1) merges' -- here with one tile of slack per tile."""
    ev = hevr.encrypt_volume(
        np.zeros((2, 2, 5), np.uint8), tmp_path / "v.zarr", keypair256[1], brick=(2, 2, 1), progress=False
    )
    cam = hevr.Camera((2.0, 0.5, 8.0), (2.0, 0.5, 0.5), width=9, height=9)
    g, _, n_tiles = _graph(ev, cam, 32, "nearest")
    assert (g.map_tasks, g.edges, n_tiles) == (5, 5, 1)  # five bricks, one tile
    assert len(dict(g.dsk)) <= g.map_tasks + g.edges + g.edges / (FAN_IN - 1) + n_tiles


@pytest.mark.parametrize("parallel", [False, True], ids=["perspective", "parallel"])
def test_splitting_bricks_at_most_doubles_edges(family, parallel):
    """Half a brick's grown box lies in the brick's: its footprint rectangle and tiles do too."""
    width, height, tile = 48, 40, 8
    edges = []
    for parent_ev, child_ev in zip(family, family[1:]):
        cam = hevr.Camera.orbit(parent_ev, azimuth=-40, elevation=25, width=width, height=height, parallel=parallel)
        hit = cast_rays(cam, SHAPE, SPACING, 1.0).n_samples > 0
        parent = brick_footprints(cam, SHAPE, SPACING, parent_ev.brick, hit, tile)
        child = brick_footprints(cam, SHAPE, SPACING, child_ev.brick, hit, tile)
        axis = next(a for a in range(3) if child_ev.brick[a] != parent_ev.brick[a])
        for idx, fp in child.items():
            up = tuple(i // 2 if a == axis else i for a, i in enumerate(idx))
            assert up in parent, (idx, up)
            (r0, r1, c0, c1), (R0, R1, C0, C1) = fp.rect, parent[up].rect
            assert R0 <= r0 and r1 <= R1 and C0 <= c0 and c1 <= C1
            assert set(fp.tiles) <= set(parent[up].tiles)
        e_parent = sum(len(f.tiles) for f in parent.values())
        e_child = sum(len(f.tiles) for f in child.values())
        assert len(child) <= 2 * len(parent) and e_child <= 2 * e_parent
        g, _, _ = _graph(child_ev, cam, tile)
        assert g.edges == e_child
        edges.append(e_child)
    assert edges == sorted(edges) and edges[-1] > edges[0]  # more bricks do cost more edges


@pytest.mark.parametrize("parallel", [False, True], ids=["perspective", "parallel"])
@pytest.mark.parametrize("width, height", [(64, 64), (128, 96)])
def test_many_small_bricks_have_small_footprints(parallel, width, height):
    shape, brick = (16, 16, 16), (2, 2, 2)
    cam = hevr.Camera.orbit(shape, azimuth=35, elevation=-25, width=width, height=height, parallel=parallel)
    hit = cast_rays(cam, shape, (1, 1, 1), 1.0).n_samples > 0
    prints = brick_footprints(cam, shape, (1, 1, 1), brick, hit, 8)
    assert len(prints) == 512  # the camera sees every brick
    P = width * height
    areas = np.array([(f.rect[1] - f.rect[0]) * (f.rect[3] - f.rect[2]) for f in prints.values()])
    assert areas.max() <= 0.1 * P  # a 2³ brick of a 16³ volume covers a few % of the view, never all of it
    assert areas.sum() <= 0.06 * len(prints) * P  # the map tasks together cast far fewer than bricks × pixels rays
    n_tiles = TileLayout(width, height, 8).n_tiles
    assert max(len(f.tiles) for f in prints.values()) <= n_tiles / 4  # a few tiles, not all of them


def test_map_tasks_cast_only_their_footprint(family):
    """In the graph every map task holds its brick's bounded footprint, not the whole image."""
    ev = family[-1]  # 128 bricks
    cam = hevr.Camera.orbit(ev, azimuth=30, elevation=20, width=64, height=48)
    g, _, _ = _graph(ev, cam, 8)
    tasks = [t for k, t in dict(g.dsk).items() if str(k).startswith("hevr-map")]
    fps = [t[8] for t in tasks]
    assert len(fps) == g.map_tasks == 128 and all(isinstance(f, Footprint) for f in fps)
    areas = [f.pixels(64).size for f in fps]
    assert max(areas) < 0.25 * 64 * 48 and sum(areas) < 0.1 * len(fps) * 64 * 48


@pytest.mark.parametrize("grid, width", [(8, 256), (16, 128)])
def test_footprint_memory_is_linear_in_bricks_plus_pixels(grid, width):
    """Peak memory of the client's footprint pass is O(B + P); a B × P table would be far bigger."""
    shape = (grid * 2, grid * 2, grid * 2)
    B, P = grid**3, width * width
    cam = hevr.Camera.orbit(shape, azimuth=30, elevation=20, width=width, height=width)
    hit = np.ones(P, bool)
    tracemalloc.start()
    try:
        prints = brick_footprints(cam, shape, (1, 1, 1), (2, 2, 2), hit, 16)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert len(prints) == B
    assert peak <= 2048 * B + 64 * P, peak
    assert peak < B * P / 4  # even a bool per (brick, pixel) would not fit


def test_resident_bricks_are_passed_to_their_map_tasks(family):
    ev = family[1]
    cam = hevr.Camera.orbit(ev, azimuth=10, elevation=10, width=16, height=16)
    plain, _, _ = _graph(ev, cam, 8)
    marks = {idx: ("resident", idx) for idx in ev.brick_indices()}
    res, _, _ = _graph(ev, cam, 8, resident=marks)
    assert (res.map_tasks, res.edges, len(dict(res.dsk))) == (plain.map_tasks, plain.edges, len(dict(plain.dsk)))
    assert set(dict(res.dsk)).isdisjoint(dict(plain.dsk))  # another token: no key collision with streamed
    for key, task in dict(res.dsk).items():
        if str(key).startswith("hevr-map"):
            assert task[-1] == ("resident", task[3])
    for key, task in dict(plain.dsk).items():
        if str(key).startswith("hevr-map"):
            assert task[-1] is None
    assert all(isinstance(k, str) for k in dict(res.dsk))


def test_tile_row_pieces_split_rays_not_outputs(family):
    """With bands every (brick, tile) output still comes from exactly one map task, and each
    piece's rectangle lies in one tile row inside its brick's rectangle."""
    ev = family[-1]
    cam = hevr.Camera.orbit(ev, azimuth=35, elevation=25, width=40, height=40)
    rays = cast_rays(cam, ev.shape, ev.spacing, 1.0)
    whole = build_sums_graph(ev, cam, rays, "nearest", 1.0, 0, "scalar", 8, 25)
    split = build_sums_graph(ev, cam, rays, "nearest", 1.0, 0, "scalar", 8, 25, bands=True)
    assert split.edges == whole.edges and split.map_tasks == whole.map_tasks
    assert whole.pieces == whole.map_tasks < split.pieces <= split.edges

    def outputs(g):  # (brick, tile) pairs the map tasks emit
        return sorted(
            (task[3], t) for k, task in dict(g.dsk).items() if k.startswith("hevr-map-") for t in task[8].tiles
        )

    assert outputs(split) == outputs(whole) and len(outputs(whole)) == whole.edges
    for key, task in dict(split.dsk).items():
        if key.startswith("hevr-map-"):
            fp = task[8]
            assert fp.rect[0] // 8 == (fp.rect[1] - 1) // 8 and all(t // 5 == fp.rect[0] // 8 for t in fp.tiles)
