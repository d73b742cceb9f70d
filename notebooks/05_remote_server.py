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
# # Rendering on someone else's cluster: `hevr serve` and `hevr.connect`
#
# The key holder must never be a Dask *client* of a cluster it does not run: Dask's protocol
# unpickles what the cluster sends, so a hostile worker can run code in the key holder's process,
# where the private key is. hevr draws the paper's boundary instead:
#
# * **the server** (`hevr serve STORE --workers N`, beside the cluster) renders on ciphertexts and
#   answers with data only — `.hevr` images, length-prefixed units, JSON;
# * **the key holder** (`hevr.connect(URL)`) sends requests that name a view and a stored channel
#   (never the mode's density or transfer function: colour is applied here), checks every public
#   field of each answer against what it computes itself, draws the verification seed *after* it
#   holds the image, and decrypts.
#
# Here both run on this machine: the server as a separate process on 127.0.0.1, as its operator
# would start it on theirs. Sizes are small (512-bit demo key, 24³ phantom); change them below.

# %% tags=["parameters"]
# --- parameters --------------------------------------------------------------------
KEY_BITS = 512          # demo size only! use 2048 (or more) for real data
PHANTOM_SIZE = 24
VECTOR_DIMS = 4
BRICK = 8
N_WORKERS = 2
IMAGE = 64
TF = [(0.15, "blue"), (0.45, "lime"), (0.8, "red")]

# %%
import json
import os
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

import hevr
from hevr.remote.protocol import RenderRequest

WORKDIR = tempfile.mkdtemp(prefix="hevr-remote-")
with warnings.catch_warnings():
    warnings.simplefilter("ignore", hevr.InsecureKeyWarning)
    pub, priv = hevr.generate_keypair(bits=KEY_BITS)
vol = hevr.phantom(PHANTOM_SIZE)
# The owner encrypts (with the private key: the fast path) a verifiable store, then hands it over.
t0 = time.perf_counter()
ev = hevr.encrypt_volume(vol, os.path.join(WORKDIR, "phantom.zarr"), priv, brick=BRICK, vector_dims=VECTOR_DIMS,
                         verifiable=True, progress=False)
print(f"encrypted {PHANTOM_SIZE}³ in {time.perf_counter() - t0:.1f} s; store id {ev.meta.store_id}")

# %% [markdown]
# ## The server's side: `hevr serve`
#
# What the operator types, next to the Dask scheduler (here a 2-worker local cluster it starts
# itself). It prints each store's id and the URL; it has no key and never accepts one.

# %%
server_proc = subprocess.Popen(
    [sys.executable, "-m", "hevr", "serve", os.path.join(WORKDIR, "phantom.zarr"), "--workers", str(N_WORKERS),
     "--port", "0"], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
url = None
for line in server_proc.stdout:
    print(line.rstrip().replace(WORKDIR, "WORKDIR"))
    if line.startswith("serving:"):
        url = line.split()[1]
        break
assert url is not None, "hevr serve did not start"

# %% [markdown]
# ## The key holder's side: `hevr.connect`
#
# A `RemoteVolume` takes the place of an `EncryptedVolume`: cameras, planes, `render`,
# `render_slice`, `render_frame` and the `Viewer` take it unchanged. The store's description is
# public metadata, parsed by the same strict parser that opens a local store.

# %%
server = hevr.connect(url, timeout=120)
print([{k: v for k, v in s.items() if k != "fingerprint"} for s in server.stores()])
rv = server.open(ev.meta.store_id)
cam = hevr.Camera.orbit(rv, azimuth=30, elevation=20, width=IMAGE, height=IMAGE)
print("what crosses the wire for a transfer-function frame:",
      json.dumps(RenderRequest(view=cam, channel="vector").to_dict())[:160], "…")

# %%
t0 = time.perf_counter()
img = hevr.render(rv, cam, mode="tf", nodes=TF, sampling="trilinear")   # verified: the store has tags
render_s = time.perf_counter() - t0
tf_image = img.decrypt(priv)   # checks the aggregate first: a wrong image raises VerificationError
ref = hevr.render_plain(vol, cam, mode="tf", nodes=TF, sampling="trilinear", vector_dims=VECTOR_DIMS)
bound = hevr.error_bound(ev, cam, mode="tf", nodes=TF, sampling="trilinear")
local = hevr.render(ev, cam, mode="tf", nodes=TF, sampling="trilinear", verify=False, progress=False)
img.verification = None
same_bytes = img.to_bytes() == local.to_bytes()
print(f"remote TF frame: {render_s:.2f} s (render and verification round), max error "
      f"{np.abs(tf_image - ref).max():.2e} <= bound {bound.max():.2e}; same bytes as in process: {same_bytes}")

# %%
plane = hevr.Plane.coronal(rv, PHANTOM_SIZE // 2)
slice_image = hevr.render_slice(rv, plane, sampling="trilinear").decrypt(priv)
frame = hevr.render_frame(rv, cam, priv, mode="emphasize", density=0.5)   # streamed units, decrypted as they come
fig, axes = plt.subplots(1, 3, figsize=(11, 3.8))
axes[0].imshow(tf_image)
axes[0].set_title("transfer function (remote, verified)")
axes[1].imshow(slice_image, cmap="gray")
axes[1].set_title("coronal slice (remote, verified)")
axes[2].imshow(frame.image, cmap="gray")
axes[2].set_title("emphasis, streamed")
for ax in axes:
    ax.axis("off")
plt.tight_layout()
plt.show()

# %%
server.close()
server_proc.terminate()
server_proc.wait(30)

# %% tags=["summary"]
# Summary of this run (read by tests/test_notebooks.py).
summary = {
    "tf_error_ok": bool((np.abs(tf_image - ref) <= bound).all()),
    "same_bytes": bool(same_bytes),
    "slice_shape": list(slice_image.shape),
    "streamed_ciphertexts": int(frame.stats["ciphertexts"]),
    "render_s": render_s,
}
print(json.dumps(summary))
