"""Tests for hevr.rendering.planning.modes: colours, render-spec validation and combination matrices."""

from __future__ import annotations

import numpy as np
import pytest

from hevr.errors import ParameterError
from hevr.rendering.planning.modes import (
    MODES,
    SAMPLINGS,
    RenderSpec,
    combination_matrix,
    make_spec,
    normalisation_factor,
    parse_color,
)
from hevr.volume.density import encode_density


@pytest.mark.parametrize(
    "color, expected",
    [
        ((0, 0, 1), (0.0, 0.0, 1.0)),
        ([0.25, 0.5, 1.0], (0.25, 0.5, 1.0)),
        (np.array([1.0, 0.0, 0.5]), (1.0, 0.0, 0.5)),
        ("#0000ff", (0.0, 0.0, 1.0)),
        ("#FF8000", (1.0, 128 / 255, 0.0)),
        ("#f0f", (1.0, 0.0, 1.0)),
        ("red", (1.0, 0.0, 0.0)),
        (" Blue ", (0.0, 0.0, 1.0)),
        ("green", (0.0, 128 / 255, 0.0)),
        ("lime", (0.0, 1.0, 0.0)),
        ("yellow", (1.0, 1.0, 0.0)),
        ("purple", (128 / 255, 0.0, 128 / 255)),
        ("cyan", (0.0, 1.0, 1.0)),
        ("magenta", (1.0, 0.0, 1.0)),
        ("white", (1.0, 1.0, 1.0)),
        ("orange", (1.0, 165 / 255, 0.0)),
    ],
)
def test_parse_color(color: object, expected: tuple[float, float, float]) -> None:
    assert parse_color(color) == pytest.approx(expected)


@pytest.mark.parametrize(
    "color",
    [
        "#12345",
        "#gggggg",
        "chartreuse-ish",
        "",
        (1, 0),
        (0, 0, 2),
        (0, -0.1, 0),
        (0, float("nan"), 0),
        None,
        3,
        ("a", 0, 0),
    ],
)
def test_parse_color_rejects(color: object) -> None:
    with pytest.raises(ParameterError, match="color"):
        parse_color(color)


_NODES = [(0.279, (0, 0, 1)), (0.797, "red")]


def test_make_spec_roundtrip() -> None:
    spec = make_spec("tf", "trilinear", 0.5, None, _NODES, vector_dims=4)
    assert spec == RenderSpec("tf", "trilinear", 0.5, None, ((0.279, (0.0, 0.0, 1.0)), (0.797, (1.0, 0.0, 0.0))))
    assert hash(spec) == hash(make_spec("tf", "trilinear", 0.5, None, _NODES, vector_dims=4))
    assert spec.channels == 3 and spec.needs_vector
    x = make_spec("xray", "nearest", 1, 0.5, _NODES, vector_dims=None)
    assert (x.density, x.nodes, x.channels, x.needs_vector) == (None, None, 1, False)  # unused args dropped
    e = make_spec("emphasize", "nearest", 1, 0.653, _NODES, vector_dims=3)
    assert (e.density, e.nodes) == (0.653, None)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(mode="mip"), "mode: expected one of xray, emphasize, tf"),
        (dict(sampling="cubic"), "sampling: expected one of nearest, trilinear"),
        (dict(mode="emphasize", density=None), "density"),
        (dict(mode="tf", nodes=None), "nodes"),
        (dict(mode="tf", nodes=[]), "nodes"),
        (dict(mode="tf", nodes=[0.5]), r"nodes\[0\]"),
        (dict(mode="emphasize", density=1.5), "density"),
        (dict(mode="emphasize", density=-0.1), "density"),
        (dict(mode="emphasize", density=float("nan")), "density"),
        (dict(mode="tf", nodes=[(1.2, "red")]), r"nodes\[0\] density"),
        (dict(mode="tf", nodes=[(0.2, "red"), (0.5, (0, 1.5, 0))]), r"nodes\[1\]"),
        (dict(mode="tf", nodes=[(0.2, "nocolor")]), "color"),
        (dict(step=0), "step"),
        (dict(step=-1.0), "step"),
        (dict(step=float("nan")), "step"),
        (dict(mode="emphasize", density=0.5, vector_dims=None), "vector_dims=k"),
        (dict(mode="tf", vector_dims=None), "no vector channel"),
        (dict(mode="emphasize", density=0.5, vector_dims=1), "vector_dims"),
        (dict(mode="xray", has_scalar=False), "scalar"),
    ],
)
def test_make_spec_rejects(kwargs: dict, match: str) -> None:
    args = dict(mode="xray", sampling="nearest", step=1.0, density=0.5, nodes=_NODES, vector_dims=4)
    args.update(kwargs)
    with pytest.raises(ParameterError, match=match):
        make_spec(**args)


def test_constants() -> None:
    assert MODES == ("xray", "emphasize", "tf")
    assert SAMPLINGS == ("nearest", "trilinear")


@pytest.mark.parametrize("k", [2, 4, 6])
def test_combination_matrix(k: int) -> None:
    emph = make_spec("emphasize", "nearest", 1.0, 0.653, None, k)
    m = combination_matrix(emph, k)
    assert m.shape == (k, 1)
    np.testing.assert_array_equal(m[:, 0], encode_density(0.653, k))
    assert normalisation_factor(emph) == 1

    tf = make_spec("tf", "nearest", 1.0, None, _NODES + [(1.0, "#00ff00")], k)
    m = combination_matrix(tf, k)
    assert m.shape == (k, 3)
    s = encode_density(0.4, k)  # any sampled vector: s @ M == sum_i dot(s, e(d_i)) c_i
    expected = sum((s @ encode_density(d, k)) * np.array(parse_color(c)) for d, c in tf.nodes)
    np.testing.assert_allclose(s @ m, expected, atol=1e-14)
    assert normalisation_factor(tf) == 3
    assert normalisation_factor(make_spec("xray", "nearest", 1.0, None, None, None)) == 1


def test_combination_matrix_rejects_xray() -> None:
    with pytest.raises(ParameterError, match="mode"):
        combination_matrix(make_spec("xray", "nearest", 1.0, None, None, None), 4)


def test_duplicate_transfer_function_densities_are_refused():
    with pytest.raises(
        ParameterError,
        match=r"nodes: expected distinct densities, got 0.5 twice \(nodes\[0\] "
        r"and nodes\[2\]\)",
    ):
        make_spec("tf", "nearest", 1.0, None, [(0.5, "red"), (0.7, "blue"), (0.5, "green")], 4, True)
    spec = make_spec("tf", "nearest", 1.0, None, [(0.5, "red"), (0.50001, "red")], 4, True)  # close is fine
    assert spec.n_nodes == 2
