# ---
# jupyter:
#   jupytext:
#     formats: ipynb,py:percent
#   kernelspec:
#     display_name: Python 3 (ipykernel)
#     language: python
#     name: python3
# ---

# %% [markdown]
# # Emphasis and transfer functions on an encrypted volume
#
# This notebook reproduces, on the encrypted phantom, the two result figures of
# Mazza, Patel & Viola (TVCG 2020):
#
# * the **emphasis figure**: an X-ray image, then the same view emphasising the
#   normalised densities 0.331, 0.653 and 0.781 (the large sphere, the small sphere and
#   the cube of the phantom);
# * the **colour figure**: four transfer functions (TFs), each a list of
#   *(density, colour)* nodes.
#
# Every encrypted image is shown above its plaintext reference (`hevr.render_plain`).
# Finally `hevr.Viewer` explores the volume interactively: since emphasis and TF modes
# are *linear* in the stored density encoding, the server keeps the per-view encrypted
# ray sums (`render(..., cache=True)`, the default) and a new density, colour or node only
# redoes the cheap per-pixel step.
#
# Sizes are deliberately small (24³ phantom, 40×40 images, 512-bit key); change them in
# the next cell.

# %% tags=["parameters"]
# --- parameters --------------------------------------------------------------------
KEY_BITS = 512          # demo size only! use 2048 (or more) for real data
PHANTOM_SIZE = 24
VECTOR_DIMS = 4         # k of the density encoding (Alg. 4)
BRICK = 12
N_WORKERS = 2
AZIMUTH, ELEVATION = 30, 20
WIDTH, HEIGHT = 40, 40
SAMPLING = "trilinear"
STEP = 1.0

# The paper's settings live in one module, hevr.paper (shared with the CLI, demo and bench).
from hevr.paper import PAPER_DENSITIES, PAPER_TF1, PAPER_TF2, TF_NODES, tf_text

# The paper's emphasis figure: X-ray plus these emphasised densities.
EMPHASIS_DENSITIES = list(PAPER_DENSITIES)

# The paper's colour figure. Colours are (r, g, b) in [0, 1], '#rrggbb' or CSS names
# (hevr.rendering.planning.modes.parse_color); note that CSS "green" and "purple" are half-intensity
# (0, 0.5, 0) and (0.5, 0, 0.5) - the Fig. 6(d) nodes use "lime", pure green.
TRANSFER_FUNCTIONS = {
    "paper TF 1": PAPER_TF1,
    "blue 0, red 1": ((0.0, "blue"), (1.0, "red")),
    "paper TF 2": PAPER_TF2,
    "Fig. 6(d)": TF_NODES,
}
for label, nodes in TRANSFER_FUNCTIONS.items():
    print(f"{label:14s} {tf_text(nodes)}")

# %%
import io
import json
import os
import shutil
import tempfile
import textwrap
import time
import warnings

import matplotlib.pyplot as plt
import numpy as np
from distributed import Client, LocalCluster

import hevr
from hevr.rendering.planning.modes import parse_color

WORKDIR = tempfile.mkdtemp(prefix="hevr-tf-")

# %% [markdown]
# ## 1. Owner: keys and encrypted volume; server: a local cluster
#
# The same steps as in `01_quickstart.ipynb`. `vector_dims=4` stores, next to the scalar
# channel used by X-ray, the 4-dimensional density encoding that emphasis and TFs need.
# (The `InsecureKeyWarning` for the 512-bit demo key is silenced on purpose.)

# %%
with warnings.catch_warnings():
    warnings.simplefilter("ignore", hevr.InsecureKeyWarning)
    pub, priv = hevr.generate_keypair(KEY_BITS)

cluster = LocalCluster(n_workers=N_WORKERS, threads_per_worker=1, processes=True,
                       dashboard_address=":0", local_directory=WORKDIR)
client = Client(cluster)

vol = hevr.phantom(PHANTOM_SIZE)
ev = hevr.encrypt_volume(vol, os.path.join(WORKDIR, "phantom.zarr"), priv,
                         brick=BRICK, vector_dims=VECTOR_DIMS, progress=False)
cam = hevr.Camera.orbit(ev, azimuth=AZIMUTH, elevation=ELEVATION, width=WIDTH, height=HEIGHT)
hevr.clear_cache()   # start without cached ray sums, even when this cell is re-run
print(repr(ev).replace(WORKDIR, "WORKDIR"))   # the temporary folder's path is machine-specific
print("phantom density levels:", hevr.PHANTOM_LEVELS)

# %% [markdown]
# ## 2. Render, decrypt, compare
#
# `render_and_check` renders on the server, decrypts on the client, renders the
# plaintext reference and asserts that every pixel is within the guaranteed error bound
# (`hevr.error_bound`). It also records the render statistics: `map_tasks` is
# the number of per-brick tasks that ran (0 when the cached ray sums were reused).

# %%
results = []   # one row per rendered image

def render_and_check(mode, label, **params):
    t0 = time.perf_counter()
    img = hevr.render(ev, cam, mode=mode, sampling=SAMPLING, step=STEP, progress=False, **params)
    seconds = time.perf_counter() - t0
    enc = img.decrypt(priv)
    ref = hevr.render_plain(vol, cam, mode=mode, sampling=SAMPLING, step=STEP,
                            vector_dims=VECTOR_DIMS, **params)
    bound = hevr.error_bound(ev, cam, mode=mode, sampling=SAMPLING, step=STEP, **params)
    err = np.abs(enc - ref)
    assert (err <= bound).all(), f"{label}: max error {err.max():.3g} exceeds the bound"
    row = {"label": label, "mode": mode, "map_tasks": img.stats["map_tasks"],
           "reused_ray_sums": img.stats["reused_ray_sums"], "seconds": round(seconds, 3),
           "max_error": float(err.max()), "bound": float(bound.max())}
    results.append(row)
    return enc, ref, row

def print_rows(rows):
    print(f"{'image':56s} {'map tasks':>9s} {'reused':>6s} {'time s':>7s} {'max err':>9s} {'bound':>9s}")
    for r in rows:
        print(f"{r['label']:56s} {r['map_tasks']:9d} {r['reused_ray_sums']!s:>6s} "
              f"{r['seconds']:7.2f} {r['max_error']:9.2g} {r['bound']:9.2g}")


# %% [markdown]
# ## 3. The emphasis figure
#
# X-ray averages the scalar channel along each ray. Emphasis averages
# `dot(s, e(density))`, where `s` is the sampled encoded vector and `e` the density
# encoding: voxels whose density is close to the emphasised one light up. The first
# emphasis image computes the encrypted ray sums of the vector channel; the next two
# reuse them (`map_tasks == 0`).

# %%
emphasis = [render_and_check("xray", "X-ray")]
for d in EMPHASIS_DENSITIES:
    emphasis.append(render_and_check("emphasize", f"emphasis {d:.3f}", density=d))
print_rows([row for _, _, row in emphasis])

fig, axes = plt.subplots(2, len(emphasis), figsize=(2.6 * len(emphasis), 5.4), squeeze=False)
for j, (enc, ref, row) in enumerate(emphasis):
    vmax = max(float(ref.max()), 1e-12)
    for i, (arr, kind) in enumerate(((enc, "encrypted"), (ref, "plaintext"))):
        axes[i, j].imshow(arr, cmap="gray", vmin=0, vmax=vmax)
        axes[i, j].set_title(f"{row['label']}\n{kind}", fontsize=9)
        axes[i, j].axis("off")
fig.suptitle("Emphasis figure: encrypted render (top) vs plaintext reference (bottom)")
plt.tight_layout()
plt.show()

# %% [markdown]
# ## 4. The colour figure
#
# A TF with nodes *(d_i, c_i)* averages `Σ_i dot(s, e(d_i))·c_i / K` along each ray, an
# RGB image. All four TFs reuse the ray sums cached for the emphasis images. Each
# encrypted image and its reference share one display window (0 to the reference's
# maximum, jointly over the channels) so colours are comparable.

# %%
colour = []
for label, nodes in TRANSFER_FUNCTIONS.items():
    nodes = [(d, parse_color(c)) for d, c in nodes]
    colour.append(render_and_check("tf", "TF " + label, nodes=nodes))
print_rows([row for _, _, row in colour])

fig, axes = plt.subplots(2, len(colour), figsize=(3.0 * len(colour), 7.2), squeeze=False)
for j, (enc, ref, row) in enumerate(colour):
    window = (0.0, max(float(ref.max()), 1e-12))
    for i, (arr, kind) in enumerate(((enc, "encrypted"), (ref, "plaintext"))):
        axes[i, j].imshow(hevr.to_uint8(arr, window))
        title = "\n".join(textwrap.wrap(row["label"][len("TF "):], 28))
        axes[i, j].set_title(f"{title}\n{kind}", fontsize=8)
        axes[i, j].axis("off")
fig.suptitle("Colour figure: encrypted render (top) vs plaintext reference (bottom)")
plt.tight_layout()
plt.show()

# %% [markdown]
# ## 5. The viewer: camera, mode and a transfer-function editor
#
# `hevr.Viewer` runs in the key holder's notebook: it sends render requests to the cluster
# (`client=`), decrypts the frames here and shows them with the frame time and, since this
# notebook has the plaintext volume, the largest error against `hevr.render_plain`.
# Sliders render when released. The transfer-function editor has one row per node
# (density slider, colour picker, remove button) and an *add node* button. A new colour,
# density, node or mode on the same camera re-colours the frame the viewer already holds,
# on this machine (the frame is finished on the client, `hevr.Frame`): the status line says
# `re-coloured on the client in N ms, no server` and nothing is sent to the cluster.
#
# Widgets need a live Jupyter front end; on a code host (or headless, as in the test
# suite) they show as text. So the next cells also drive the viewer from code, exactly as
# the widgets would, and draw its frames with matplotlib.

# %%
viewer = hevr.Viewer(ev, priv, volume=vol, width=WIDTH, height=HEIGHT, mode="tf",
                     sampling=SAMPLING, client=client)
viewer   # camera sliders, mode, sampling, density, TF editor, frame and status line

# %%
import PIL.Image

frames = [("start: paper TF 1", viewer.history[-1], bytes(viewer.image.value))]

def drive(label, action):
    """Do what a click or a slider release would do; keep the frame it shows."""
    action()
    frames.append((label, viewer.history[-1], bytes(viewer.image.value)))

drive("first node's colour -> lime", lambda: setattr(viewer.node_rows[0][1], "value", "#00ff00"))
drive("add node 0.5, yellow", lambda: viewer.add_node(0.5, "yellow"))
drive("remove the last node", lambda: viewer.node_rows[-1][2].click())
drive("emphasis mode", lambda: setattr(viewer.mode, "value", "emphasize"))
drive("camera: azimuth 120", lambda: setattr(viewer.azimuth, "value", 120.0))
drive("back to the TF", lambda: setattr(viewer.mode, "value", "tf"))

print(f"{'step':32s} {'map tasks':>9s} {'reused':>6s} {'seconds':>8s} {'max err':>9s} {'bound':>9s}")
for label, h, _ in frames:
    print(f"{label:32s} {h['map_tasks']:9d} {h['reused_ray_sums']!s:>6s} {h['seconds']:8.2f} "
          f"{h['error']:9.2g} {h['bound']:9.2g}")

fig, axes = plt.subplots(1, len(frames), figsize=(2.2 * len(frames), 2.8), squeeze=False)
for ax, (label, h, png) in zip(axes[0], frames):
    ax.imshow(np.asarray(PIL.Image.open(io.BytesIO(png))), cmap="gray")   # grey frames are 2-D
    ax.set_title("\n".join(textwrap.wrap(label, 18)), fontsize=8)
    ax.axis("off")
fig.suptitle("The viewer's frames, driven from code (decrypted in this notebook)")
plt.tight_layout()
plt.show()

for label, h, _ in frames:
    assert h["error"] <= h["bound"], (label, h)
camera_moves = {"start: paper TF 1", "camera: azimuth 120"}
for label, h, _ in frames:
    if label not in camera_moves:   # same camera: re-coloured, no map step
        assert h["reused_ray_sums"] is True and h["map_tasks"] == 0, (label, h)
assert frames[5][1]["map_tasks"] > 0   # a new camera needs the map step
viewer_summary = {"frames": len(frames),
                  "map_tasks": [h["map_tasks"] for _, h, _ in frames],
                  "reused": [h["reused_ray_sums"] for _, h, _ in frames]}
print(viewer_summary)

# %% [markdown]
# ## 6. Clean up

# %%
client.close()
cluster.close()
shutil.rmtree(WORKDIR, ignore_errors=True)

# %% tags=["summary"]
# Summary of this run (read by tests/test_notebooks.py).
summary = {
    "images": [{k: r[k] for k in ("label", "map_tasks", "reused_ray_sums", "max_error", "bound")}
               for r in results],
    "viewer": viewer_summary,
}
print(json.dumps(summary))
