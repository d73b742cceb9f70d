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
# # Scaling: workers, brick size and key size
#
# Three small experiments on the encrypted phantom:
#
# * **(a) workers** - the same render on a 1-worker and a 2-worker `LocalCluster`
#   (speed-up);
# * **(b) brick size** - encryption time, render time and number of map tasks for
#   several brick edges;
# * **(c) key size** - owner-side encryption time per voxel, render time and decryption
#   time for several Paillier key sizes.
#
# The defaults finish in well under a minute on 2 cores. All sizes are parameters in the
# next cell: scale them up (e.g. `PHANTOM_SIZE = 100`, `KEY_SIZES = [1024, 2048]`,
# `WORKER_COUNTS = [1, 2, 4, 8]`) on a bigger machine. Timings on a shared machine are
# noisy: each render is repeated `REPEATS` times and the fastest run is reported.

# %% tags=["parameters"]
# --- parameters --------------------------------------------------------------------
from hevr.paper import PAPER_DENSITIES  # the paper's settings, shared with the CLI and bench

PHANTOM_SIZE = 24
SAMPLING = "trilinear"
AZIMUTH, ELEVATION = 30, 20
REPEATS = 2                 # timed repetitions per render (the minimum is reported)

# (a) workers: one render, timed on a cluster scaled to each of these sizes (ascending)
WORKER_COUNTS = [1, 2]
A_KEY_BITS = 512
A_BRICK = 8
A_IMAGE = 64                # pixels per side
A_MODE, A_DENSITY = "emphasize", PAPER_DENSITIES[1]   # the vector modes do the most work per brick

# (b) brick size, and (c) key size: run on one cluster of N_WORKERS workers
N_WORKERS = 2
IMAGE = 40
BRICK_SIZES = [6, 8, 12]
B_KEY_BITS = 512
KEY_SIZES = [256, 512, 1024]
C_BRICK = 12
RAW_ENCRYPTIONS = 100       # ciphertexts for the single-core per-value timing in (c)
VECTOR_DIMS_BC = None       # None: scalar channel only (X-ray); 4 adds the density encoding

# %%
import importlib
import json
import math
import os
import shutil
import tempfile
import time
import warnings

import matplotlib.pyplot as plt
import numpy as np
from distributed import Client, LocalCluster

import hevr

# Small keys are the point of this experiment: silence the InsecureKeyWarning.
warnings.filterwarnings("ignore", category=hevr.InsecureKeyWarning)

WORKDIR = tempfile.mkdtemp(prefix="hevr-scaling-")
vol = hevr.phantom(PHANTOM_SIZE)
NOTEBOOK_T0 = time.perf_counter()

def start_cluster(n_workers):
    cluster = LocalCluster(n_workers=n_workers, threads_per_worker=1, processes=True,
                           dashboard_address=":0", local_directory=WORKDIR)
    return cluster, Client(cluster)

def resize(cluster, client, n, timeout=120):
    """Scale the cluster to exactly n workers and wait until they are there."""
    cluster.scale(n)
    t0 = time.perf_counter()
    while len(client.nthreads()) != n:
        if time.perf_counter() - t0 > timeout:
            raise TimeoutError(f"cluster did not reach {n} workers in {timeout} s")
        time.sleep(0.1)

def timed_render(ev, cam, repeats=REPEATS, **kw):
    """Fastest of `repeats` renders (cache=False: every run does the full map-reduce)."""
    best, img = math.inf, None
    for _ in range(repeats):
        t0 = time.perf_counter()
        img = hevr.render(ev, cam, sampling=SAMPLING, progress=False, cache=False, **kw)
        best = min(best, time.perf_counter() - t0)
    return best, img

def check(ev, cam, img, priv, **kw):
    """Decrypt and assert the image is within the error bound of the plaintext render."""
    enc = img.decrypt(priv)
    ref = hevr.render_plain(vol, cam, sampling=SAMPLING, vector_dims=ev.vector_dims, **kw)
    bound = hevr.error_bound(ev, cam, sampling=SAMPLING, **kw)
    assert (np.abs(enc - ref) <= bound).all()
    return enc


# %% [markdown]
# ## (a) 1 vs 2 workers
#
# The volume is encrypted once (on Dask's default scheduler, before any cluster
# exists). Then one `LocalCluster` is started with `WORKER_COUNTS[0]` workers and scaled
# up step by step; at each size every worker is warmed up (hevr imported, one tiny
# render) before the render is timed.

# %%
pub_a, priv_a = hevr.generate_keypair(A_KEY_BITS)
ev_a = hevr.encrypt_volume(vol, os.path.join(WORKDIR, "a.zarr"), priv_a, brick=A_BRICK,
                           vector_dims=4, progress=False)
cam_a = hevr.Camera.orbit(ev_a, azimuth=AZIMUTH, elevation=ELEVATION, width=A_IMAGE, height=A_IMAGE)
warm_cam = hevr.Camera.orbit(ev_a, azimuth=AZIMUTH, elevation=ELEVATION, width=8, height=8)

def warm_up():
    importlib.import_module("hevr.rendering.encrypted")   # runs on every worker

cluster, client = start_cluster(WORKER_COUNTS[0])
worker_seconds = {}
for n in WORKER_COUNTS:
    resize(cluster, client, n)
    client.run(warm_up)
    hevr.render(ev_a, warm_cam, mode=A_MODE, density=A_DENSITY, sampling=SAMPLING,
                progress=False, cache=False)
    seconds, img_a = timed_render(ev_a, cam_a, mode=A_MODE, density=A_DENSITY)
    check(ev_a, cam_a, img_a, priv_a, mode=A_MODE, density=A_DENSITY)
    worker_seconds[n] = seconds
    print(f"{n} worker(s): {seconds:.2f} s, {img_a.stats['map_tasks']} map tasks")

base = worker_seconds[WORKER_COUNTS[0]]
speedups = {n: base / s for n, s in worker_seconds.items()}
for n in WORKER_COUNTS[1:]:
    print(f"speed-up {WORKER_COUNTS[0]} -> {n} workers: {speedups[n]:.2f}x")

fig, ax = plt.subplots(figsize=(4, 3))
ax.bar([str(n) for n in WORKER_COUNTS], [worker_seconds[n] for n in WORKER_COUNTS], color="tab:blue")
for i, n in enumerate(WORKER_COUNTS):
    ax.text(i, worker_seconds[n], f"{speedups[n]:.2f}x", ha="center", va="bottom")
ax.set_xlabel("workers")
ax.set_ylabel("render time (s)")
ax.set_title(f"{A_MODE}, {A_IMAGE}x{A_IMAGE} px, {A_KEY_BITS}-bit key")
plt.tight_layout()
plt.show()

# %% [markdown]
# ## (b) Brick size
#
# Each brick is one encryption task and one map task of the render. Small bricks give
# more parallelism but more per-task overhead (and rays are split into more partial
# sums to merge); large bricks give few, long tasks. The cluster is resized to
# `N_WORKERS` workers for the remaining experiments.

# %%
resize(cluster, client, N_WORKERS)
pub_b, priv_b = hevr.generate_keypair(B_KEY_BITS)

brick_rows = []
brick_images = []
for b in BRICK_SIZES:
    t0 = time.perf_counter()
    ev = hevr.encrypt_volume(vol, os.path.join(WORKDIR, f"brick{b}.zarr"), priv_b, brick=b,
                             vector_dims=VECTOR_DIMS_BC, progress=False)
    encrypt_s = time.perf_counter() - t0
    cam = hevr.Camera.orbit(ev, azimuth=AZIMUTH, elevation=ELEVATION, width=IMAGE, height=IMAGE)
    render_s, img = timed_render(ev, cam, mode="xray")
    brick_images.append(check(ev, cam, img, priv_b, mode="xray"))
    brick_rows.append({"brick": b, "bricks": int(np.prod(ev.grid)), "encrypt_s": encrypt_s,
                       "render_s": render_s, "map_tasks": img.stats["map_tasks"]})

print(f"{'brick':>5s} {'bricks':>6s} {'map tasks':>9s} {'encrypt s':>9s} {'render s':>8s}")
for r in brick_rows:
    print(f"{r['brick']:5d} {r['bricks']:6d} {r['map_tasks']:9d} {r['encrypt_s']:9.2f} {r['render_s']:8.2f}")
identical = all(np.array_equal(brick_images[0], im) for im in brick_images[1:])
print("decrypted images identical for every brick size:", identical)

fig, ax = plt.subplots(figsize=(5, 3.2))
xs = [r["brick"] for r in brick_rows]
ax.plot(xs, [r["encrypt_s"] for r in brick_rows], "o-", label="encryption")
ax.plot(xs, [r["render_s"] for r in brick_rows], "s-", label="render")
for r in brick_rows:
    ax.annotate(f"{r['map_tasks']} tasks", (r["brick"], r["render_s"]),
                textcoords="offset points", xytext=(0, 6), ha="center", fontsize=8)
ax.set_xlabel("brick edge (voxels)")
ax.set_ylabel("seconds")
ax.set_xticks(xs)
ax.set_title(f"{PHANTOM_SIZE}³ phantom, {B_KEY_BITS}-bit key, {N_WORKERS} workers")
ax.legend()
plt.tight_layout()
plt.show()

# %% [markdown]
# ## (c) Key size
#
# Paillier ciphertexts are numbers modulo *n*², so every operation gets slower as the
# key grows (roughly cubically for exponentiations). We measure
#
# * owner-side encryption: `encrypt_volume` with the private key (fast CRT path, run on
#   the cluster) per voxel, plus single-core `priv.encrypt_array` (owner fast path) and
#   `pub.encrypt_array` (public key only) per value;
# * the render (server) and the decryption (client) of one X-ray image.

# %%
key_rows = []
for bits in KEY_SIZES:
    pub, priv = hevr.generate_keypair(bits)
    values = list(range(RAW_ENCRYPTIONS))
    t0 = time.perf_counter()
    priv.encrypt_array(values)          # owner's fast path (uses p and q)
    owner_raw = (time.perf_counter() - t0) / RAW_ENCRYPTIONS
    t0 = time.perf_counter()
    pub.encrypt_array(values)           # what anyone holding only the public key can do
    public_raw = (time.perf_counter() - t0) / RAW_ENCRYPTIONS

    t0 = time.perf_counter()
    ev = hevr.encrypt_volume(vol, os.path.join(WORKDIR, f"key{bits}.zarr"), priv, brick=C_BRICK,
                             vector_dims=VECTOR_DIMS_BC, progress=False)
    per_voxel = (time.perf_counter() - t0) / vol.size
    cam = hevr.Camera.orbit(ev, azimuth=AZIMUTH, elevation=ELEVATION, width=IMAGE, height=IMAGE)
    render_s, img = timed_render(ev, cam, mode="xray")
    t0 = time.perf_counter()
    img.decrypt(priv)
    decrypt_s = time.perf_counter() - t0
    check(ev, cam, img, priv, mode="xray")
    key_rows.append({"bits": bits, "volume_us_per_voxel": 1e6 * per_voxel,
                     "owner_us": 1e6 * owner_raw, "public_us": 1e6 * public_raw,
                     "render_s": render_s, "decrypt_s": decrypt_s,
                     "image_ciphertexts": img.n_ciphertexts})

print(f"{'bits':>5s} {'volume us/voxel':>15s} {'owner us/value':>15s} {'public us/value':>15s} "
      f"{'render s':>8s} {'decrypt s':>9s} {'image cts':>9s}")
for r in key_rows:
    print(f"{r['bits']:5d} {r['volume_us_per_voxel']:15.1f} {r['owner_us']:15.1f} {r['public_us']:15.1f} "
          f"{r['render_s']:8.2f} {r['decrypt_s']:9.3f} {r['image_ciphertexts']:9d}")

fig, axes = plt.subplots(1, 2, figsize=(9, 3.2))
bits = [r["bits"] for r in key_rows]
axes[0].plot(bits, [r["volume_us_per_voxel"] for r in key_rows], "o-",
             label=f"encrypt_volume ({N_WORKERS} workers)")
axes[0].plot(bits, [r["owner_us"] for r in key_rows], "s-", label="priv.encrypt_array (1 core)")
axes[0].plot(bits, [r["public_us"] for r in key_rows], "^-", label="pub.encrypt_array (1 core)")
axes[0].set_ylabel("µs per voxel / value")
axes[0].set_title("owner-side encryption")
axes[1].plot(bits, [r["render_s"] for r in key_rows], "o-", label="render (server)")
axes[1].plot(bits, [r["decrypt_s"] for r in key_rows], "s-", label="decrypt (client)")
axes[1].set_ylabel("seconds")
axes[1].set_title(f"one {IMAGE}x{IMAGE} X-ray image")
for ax in axes:
    ax.set_xscale("log", base=2)
    ax.set_yscale("log")
    ax.set_xticks(bits, [str(b) for b in bits])
    ax.minorticks_off()
    ax.set_xlabel("key bits")
    ax.legend(fontsize=8)
plt.tight_layout()
plt.show()

# %% [markdown]
# ## Clean up

# %%
client.close()
cluster.close()
shutil.rmtree(WORKDIR, ignore_errors=True)
print(f"total {time.perf_counter() - NOTEBOOK_T0:.1f} s")

# %% tags=["summary"]
# Summary of this run (read by tests/test_notebooks.py).
summary = {
    "worker_seconds": {str(n): round(s, 3) for n, s in worker_seconds.items()},
    "speedup": {str(n): round(s, 3) for n, s in speedups.items()},
    "bricks": brick_rows,
    "brick_images_identical": identical,
    "keys": key_rows,
}
print(json.dumps(summary))
