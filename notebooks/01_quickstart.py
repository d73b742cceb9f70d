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
# # hevr quick start: render an encrypted volume
#
# This notebook walks through the whole privacy-preserving pipeline of
# Mazza, Patel & Viola, *Homomorphic-Encrypted Volume Rendering* (IEEE TVCG 2020):
#
# | role | who | does |
# |---|---|---|
# | **data owner** | you | makes a Paillier key pair, encrypts the volume voxel by voxel |
# | **server** | an untrusted Dask cluster | ray-casts the *ciphertexts* into an encrypted image |
# | **client** | you again (holds the secret key) | decrypts the image and looks at it |
#
# Here all three roles run on this machine: a 2-worker `distributed.LocalCluster`
# stands in for the remote server. Everything the notebook writes goes to one
# `tempfile.mkdtemp()` folder, which is deleted at the end.
#
# The parameters are all in the next cell; the defaults are small so that the notebook
# runs in a few seconds.

# %% tags=["parameters"]
# --- parameters --------------------------------------------------------------------
KEY_BITS = 512        # demo size only! 2048 bits is the smallest secure Paillier key
PHANTOM_SIZE = 24     # the paper's test object, PHANTOM_SIZE**3 voxels
VECTOR_DIMS = 4       # k of the paper's density encoding (Alg. 4); needed by emphasis / TF modes
BRICK = 12            # brick edge in voxels: the server runs one map task per brick
N_WORKERS = 2         # Dask worker processes of the stand-in server
AZIMUTH, ELEVATION = 30, 20   # degrees, camera on a sphere around the volume
WIDTH, HEIGHT = 40, 40        # image size in pixels
SAMPLING = "trilinear"        # or "nearest"
STEP = 1.0                    # sample spacing along each ray, world units
KEEP_FILES = False            # keep the temporary folder (encrypted store, image, PNG)?

# %%
import json
import os
import shutil
import tempfile
import time
import warnings
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
from distributed import Client, LocalCluster

import hevr

WORKDIR = tempfile.mkdtemp(prefix="hevr-quickstart-")
# Printed paths show this folder as WORKDIR: its absolute path is machine-specific.
print("hevr", hevr.__version__, "- temporary files in WORKDIR =", os.path.basename(WORKDIR))

# %% [markdown]
# ## 1. Keys (data owner)
#
# `hevr.generate_keypair(bits)` returns the public key (the modulus *n*, shared with the
# server) and the private key (the primes *p*, *q*, kept by the owner). Keys below 2048
# bits are **not secure** and hevr says so with an `InsecureKeyWarning`; we use 512 bits
# only to keep this demo fast. For real data use `hevr.generate_keypair(2048)` (the
# default) and store the private key with `priv.save("key.json")` (written with mode 0600).

# %%
with warnings.catch_warnings(record=True) as caught:
    warnings.simplefilter("always")
    pub, priv = hevr.generate_keypair(KEY_BITS)
for w in caught:
    print(f"{w.category.__name__}: {w.message}")
print("public key:", pub.bits, "bits, fingerprint", pub.fingerprint[:16], "...")

# %% [markdown]
# ## 2. The volume
#
# `hevr.phantom(size)` is the paper's test object: a uint8 volume with a large sphere,
# a small sphere and a cube at three density levels (normalised densities 0.331, 0.653
# and 0.781 - the values used by the paper's emphasis figure). Any 3-D array works;
# `hevr.load_volume` reads .npy, .raw, NRRD, NIfTI and DICOM.

# %%
vol = hevr.phantom(PHANTOM_SIZE)
print("shape (nz, ny, nx):", vol.shape, "dtype:", vol.dtype, "values:", np.unique(vol))
print("phantom density levels:", hevr.PHANTOM_LEVELS)

fig, ax = plt.subplots(figsize=(3, 3))
ax.imshow(vol[vol.shape[0] // 2], cmap="gray", vmin=0, vmax=255)
ax.set_title("plaintext mid slice (owner only)")
ax.axis("off")
plt.show()

# %% [markdown]
# ## 3. Start the stand-in server
#
# `hevr.render` and `hevr.encrypt_volume` run on the active Dask scheduler: the
# `distributed.Client` created here, otherwise Dask's default scheduler. Worker scratch
# space goes to our temporary folder as well.

# %%
cluster = LocalCluster(n_workers=N_WORKERS, threads_per_worker=1, processes=True,
                       dashboard_address=":0", local_directory=WORKDIR)
client = Client(cluster)
print(client)

# %% [markdown]
# ## 4. Encrypt the volume (data owner)
#
# Every voxel becomes a Paillier ciphertext (an integer modulo *n*²). With
# `vector_dims=4` each voxel additionally stores the paper's 4-dimensional density
# encoding (Alg. 4), which the emphasis and transfer-function modes need
# (see `02_transfer_functions.ipynb`). Passing the **private** key selects the owner's
# fast path (same ciphertext distribution, computed with *p* and *q*); the public key
# works too, only slower. The result is a Zarr store, one chunk per brick.

# %%
t0 = time.perf_counter()
ev = hevr.encrypt_volume(vol, os.path.join(WORKDIR, "phantom.zarr"), priv,
                         brick=BRICK, vector_dims=VECTOR_DIMS, progress=False)
encrypt_seconds = time.perf_counter() - t0
n_ciphertexts = vol.size * (1 + VECTOR_DIMS)
print(repr(ev).replace(WORKDIR, "WORKDIR"))
print(f"{n_ciphertexts} ciphertexts in {encrypt_seconds:.2f} s "
      f"({1e6 * encrypt_seconds / n_ciphertexts:.0f} us each), bricks: {ev.grid}")

# %% [markdown]
# ### What the server sees - and what it never sees
#
# The server gets the Zarr store and, per frame, a camera and the render settings. It sees
#
# * the **public key** (*n*, its size and fingerprint) - enough to add ciphertexts and
#   multiply them by plain numbers, not to decrypt;
# * the **ciphertexts**, one per voxel and channel - under Paillier they are
#   indistinguishable from random numbers modulo *n*²;
# * public **metadata**: volume shape, voxel spacing, brick size, value range and
#   the number encoding (exponents);
# * the **camera** and the render parameters (mode, sampling, step, and the emphasised
#   density or transfer-function nodes). These are not hidden in this scheme.
#
# It never sees the secret key (*p*, *q*, λ, μ), any voxel value, or any pixel of the
# rendered image. The next cell checks the first point on the files themselves: neither
# prime appears anywhere in the store, in binary or in decimal.

# %%
meta = ev.meta.to_dict()
print(json.dumps({k: meta[k] for k in ("shape", "spacing", "brick", "value_range", "channels")}))
print("public key in the store:", meta["public_key"]["bits"], "bits, fingerprint",
      meta["public_key"]["fingerprint"][:16], "...")

secrets = []
for prime in (int(priv.p), int(priv.q)):
    secrets += [prime.to_bytes((prime.bit_length() + 7) // 8, "big"), str(prime).encode()]
store_files = [os.path.join(d, f) for d, _, fs in os.walk(ev.path) for f in fs]
store_bytes = sum(os.path.getsize(f) for f in store_files)
leaks = [f for f in store_files if any(s in Path(f).read_bytes() for s in secrets)]
assert not leaks, f"secret key material found in {leaks}"
print(f"{len(store_files)} store files, {store_bytes / 1e6:.1f} MB: no trace of p or q")

# %% [markdown]
# ## 5. Camera
#
# `hevr.Camera.orbit` puts a perspective camera on a sphere around the volume centre
# (azimuth about the y axis, elevation upwards) and frames the whole volume.

# %%
cam = hevr.Camera.orbit(ev, azimuth=AZIMUTH, elevation=ELEVATION, width=WIDTH, height=HEIGHT)
print(cam)

# %% [markdown]
# ## 6. Render on the server
#
# `hevr.render` builds one Dask graph: a *map* task per brick sums the weighted
# ciphertexts along every ray (homomorphic additions and plaintext multiplications
# only), a *reduce* merges the partial sums per image tile, and a final per-pixel step
# divides by the number of samples. X-ray mode gives the mean value along each ray.
# The secret key is never involved.

# %%
img = hevr.render(ev, cam, mode="xray", sampling=SAMPLING, step=STEP, progress=False)
print(img)
print("stats:", img.stats)

# %% [markdown]
# ## 7. Back at the client: decrypt
#
# The encrypted image travels back as a compact `.hevr` file (many pixels are packed
# into each ciphertext). Only the private key with the matching fingerprint decrypts it;
# any other key raises `hevr.KeyMismatchError`.

# %%
frame_path = os.path.join(WORKDIR, "frame.hevr")
img.save(frame_path)
print(f"WORKDIR/frame.hevr: {os.path.getsize(frame_path) / 1e3:.1f} kB, {img.n_ciphertexts} ciphertexts")

received = hevr.load_image(frame_path)
decrypted = received.decrypt(priv)
hevr.save_png(decrypted, os.path.join(WORKDIR, "frame.png"))
print("decrypted image:", decrypted.shape, decrypted.dtype,
      f"range {decrypted.min():.3f} .. {decrypted.max():.3f}")

# %% [markdown]
# ## 8. Compare with the plaintext reference
#
# `hevr.render_plain` renders the *unencrypted* volume with the same camera and
# sampling. The encrypted pipeline works with fixed-point numbers (trilinear weights
# with 3 decimals, a 4-digit reciprocal), so the two differ slightly;
# `hevr.error_bound` gives the guaranteed per-pixel bound.

# %%
reference = hevr.render_plain(vol, cam, mode="xray", sampling=SAMPLING, step=STEP)
difference = decrypted - reference
bound = hevr.error_bound(ev, cam, mode="xray", sampling=SAMPLING, step=STEP)
max_error = float(np.abs(difference).max())
assert (np.abs(difference) <= bound).all(), "decrypted image outside the error bound"
print(f"max |decrypted - reference| = {max_error:.4g}  (bound {bound.max():.4g}, "
      f"pixel values up to {reference.max():.1f})")

fig, axes = plt.subplots(1, 3, figsize=(10, 3.4))
vmax = reference.max()
for ax, arr, title in ((axes[0], decrypted, "decrypted (encrypted render)"),
                       (axes[1], reference, "plaintext reference")):
    ax.imshow(arr, cmap="gray", vmin=0, vmax=vmax)
    ax.set_title(title)
    ax.axis("off")
lim = max(max_error, 1e-12)
im = axes[2].imshow(difference, cmap="coolwarm", vmin=-lim, vmax=lim)
axes[2].set_title(f"difference (max {max_error:.2g})")
axes[2].axis("off")
fig.colorbar(im, ax=axes[2], fraction=0.046)
plt.show()

# %% [markdown]
# ## 9. Clean up
#
# Close the client and the cluster, then remove the temporary folder (unless
# `KEEP_FILES`).

# %%
client.close()
cluster.close()
if not KEEP_FILES:
    shutil.rmtree(WORKDIR, ignore_errors=True)

# %% tags=["summary"]
# Summary of this run (read by tests/test_notebooks.py).
summary = {
    "key_bits": KEY_BITS,
    "shape": list(vol.shape),
    "image_shape": list(decrypted.shape),
    "max_error": max_error,
    "error_bound": float(bound.max()),
    "reference_max": float(reference.max()),
    "encrypt_seconds": round(encrypt_seconds, 3),
    "render_stats": {k: v for k, v in img.stats.items() if k != "seconds"},
}
print(json.dumps(summary))
