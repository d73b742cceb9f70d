"""Generate the example notebooks in this folder from plain Python source.

The ``.ipynb`` files are build products: edit this script, then run::

    python notebooks/_build.py            # (re)write 01_quickstart, 02_transfer_functions, 03_scaling
    python notebooks/_build.py --check    # exit 1 if a committed notebook differs from this script

The notebooks are written without outputs and with deterministic cell ids, so a rebuild
of unchanged source gives byte-identical files (reviewable diffs). Each notebook ends
with a cell tagged ``summary`` that prints one JSON object; ``tests/test_notebooks.py``
executes the notebooks and checks those values.
"""

from __future__ import annotations

import sys
import textwrap
from pathlib import Path

import nbformat
from nbformat.v4 import new_code_cell, new_markdown_cell, new_notebook

HERE = Path(__file__).resolve().parent


def _clean(text: str) -> str:
    return textwrap.dedent(text).strip("\n")


def md(text: str) -> tuple:
    return ("markdown", _clean(text), ())


def code(text: str, *tags: str) -> tuple:
    return ("code", _clean(text), tuple(tags))


def make_notebook(stem: str, cells: list[tuple]) -> nbformat.NotebookNode:
    nb = new_notebook()
    nb.metadata = {
        "kernelspec": {"name": "python3", "display_name": "Python 3 (ipykernel)", "language": "python"},
        "language_info": {"name": "python"},
    }
    for i, (kind, src, tags) in enumerate(cells):
        cell = new_code_cell(src) if kind == "code" else new_markdown_cell(src)
        cell.id = f"{stem.split('_')[0]}-{i:02d}"
        if tags:
            cell.metadata["tags"] = list(tags)
        nb.cells.append(cell)
    nbformat.validate(nb)
    return nb


# ---------------------------------------------------------------------------------------
# 01 quick start
# ---------------------------------------------------------------------------------------

QUICKSTART = [
    md("""
    # hevr quick start: render an encrypted volume

    This notebook walks through the whole privacy-preserving pipeline of
    Mazza, Patel & Viola, *Homomorphic-Encrypted Volume Rendering* (IEEE TVCG 2020):

    | role | who | does |
    |---|---|---|
    | **data owner** | you | makes a Paillier key pair, encrypts the volume voxel by voxel |
    | **server** | an untrusted Dask cluster | ray-casts the *ciphertexts* into an encrypted image |
    | **client** | you again (holds the secret key) | decrypts the image and looks at it |

    Here all three roles run on this machine: a 2-worker `distributed.LocalCluster`
    stands in for the remote server. Everything the notebook writes goes to one
    `tempfile.mkdtemp()` folder, which is deleted at the end.

    The parameters are all in the next cell; the defaults are small so that the notebook
    runs in a few seconds.
    """),
    code("""
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
    """, "parameters"),
    code("""
    import json
    import os
    import shutil
    import tempfile
    import time
    import warnings

    import matplotlib.pyplot as plt
    import numpy as np
    from distributed import Client, LocalCluster

    import hevr
    from hevr.rendering.encrypted import error_bound

    WORKDIR = tempfile.mkdtemp(prefix="hevr-quickstart-")
    print("hevr", hevr.__version__, "- temporary files in", WORKDIR)
    """),
    md("""
    ## 1. Keys (data owner)

    `hevr.generate_keypair(bits)` returns the public key (the modulus *n*, shared with the
    server) and the private key (the primes *p*, *q*, kept by the owner). Keys below 2048
    bits are **not secure** and hevr says so with an `InsecureKeyWarning`; we use 512 bits
    only to keep this demo fast. For real data use `hevr.generate_keypair(2048)` (the
    default) and store the private key with `priv.save("key.json")` (written with mode 0600).
    """),
    code("""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        pub, priv = hevr.generate_keypair(KEY_BITS)
    for w in caught:
        print(f"{w.category.__name__}: {w.message}")
    print("public key:", pub.bits, "bits, fingerprint", pub.fingerprint[:16], "...")
    """),
    md("""
    ## 2. The volume

    `hevr.phantom(size)` is the paper's test object: a uint8 volume with a large sphere,
    a small sphere and a cube at three density levels (normalised densities 0.331, 0.653
    and 0.781 - the values used by the paper's emphasis figure). Any 3-D array works;
    `hevr.load_volume` reads .npy, .raw, NRRD, NIfTI and DICOM.
    """),
    code("""
    vol = hevr.phantom(PHANTOM_SIZE)
    print("shape (nz, ny, nx):", vol.shape, "dtype:", vol.dtype, "values:", np.unique(vol))
    print("phantom density levels:", hevr.PHANTOM_LEVELS)

    fig, ax = plt.subplots(figsize=(3, 3))
    ax.imshow(vol[vol.shape[0] // 2], cmap="gray", vmin=0, vmax=255)
    ax.set_title("plaintext mid slice (owner only)")
    ax.axis("off")
    plt.show()
    """),
    md("""
    ## 3. Start the stand-in server

    `hevr.render` and `hevr.encrypt_volume` run on the active Dask scheduler: the
    `distributed.Client` created here, otherwise Dask's default scheduler. Worker scratch
    space goes to our temporary folder as well.
    """),
    code("""
    cluster = LocalCluster(n_workers=N_WORKERS, threads_per_worker=1, processes=True,
                           dashboard_address=":0", local_directory=WORKDIR)
    client = Client(cluster)
    print(client)
    """),
    md("""
    ## 4. Encrypt the volume (data owner)

    Every voxel becomes a Paillier ciphertext (an integer modulo *n*²). With
    `vector_dims=4` each voxel additionally stores the paper's 4-dimensional density
    encoding (Alg. 4), which the emphasis and transfer-function modes need
    (see `02_transfer_functions.ipynb`). Passing the **private** key selects the owner's
    fast path (same ciphertext distribution, computed with *p* and *q*); the public key
    works too, only slower. The result is a Zarr store, one chunk per brick.
    """),
    code("""
    t0 = time.perf_counter()
    ev = hevr.encrypt_volume(vol, os.path.join(WORKDIR, "phantom.zarr"), priv,
                             brick=BRICK, vector_dims=VECTOR_DIMS, progress=False)
    encrypt_seconds = time.perf_counter() - t0
    n_ciphertexts = vol.size * (1 + VECTOR_DIMS)
    print(ev)
    print(f"{n_ciphertexts} ciphertexts in {encrypt_seconds:.2f} s "
          f"({1e6 * encrypt_seconds / n_ciphertexts:.0f} us each), bricks: {ev.grid}")
    """),
    md("""
    ### What the server sees - and what it never sees

    The server gets the Zarr store and, per frame, a camera and the render settings. It sees

    * the **public key** (*n*, its size and fingerprint) - enough to add ciphertexts and
      multiply them by plain numbers, not to decrypt;
    * the **ciphertexts**, one per voxel and channel - under Paillier they are
      indistinguishable from random numbers modulo *n*²;
    * public **metadata**: volume shape, voxel spacing, brick size, value range and
      the number encoding (exponents);
    * the **camera** and the render parameters (mode, sampling, step, and the emphasised
      density or transfer-function nodes). These are not hidden in this scheme.

    It never sees the secret key (*p*, *q*, λ, μ), any voxel value, or any pixel of the
    rendered image. The next cell checks the first point on the files themselves: neither
    prime appears anywhere in the store, in binary or in decimal.
    """),
    code("""
    meta = ev.meta.to_dict()
    print(json.dumps({k: meta[k] for k in ("shape", "spacing", "brick", "value_range", "channels")}))
    print("public key in the store:", meta["public_key"]["bits"], "bits, fingerprint",
          meta["public_key"]["fingerprint"][:16], "...")

    secrets = []
    for prime in (int(priv.p), int(priv.q)):
        secrets += [prime.to_bytes((prime.bit_length() + 7) // 8, "big"), str(prime).encode()]
    store_files = [os.path.join(d, f) for d, _, fs in os.walk(ev.path) for f in fs]
    store_bytes = sum(os.path.getsize(f) for f in store_files)
    leaks = [f for f in store_files if any(s in open(f, "rb").read() for s in secrets)]
    assert not leaks, f"secret key material found in {leaks}"
    print(f"{len(store_files)} store files, {store_bytes / 1e6:.1f} MB: no trace of p or q")
    """),
    md("""
    ## 5. Camera

    `hevr.Camera.orbit` puts a perspective camera on a sphere around the volume centre
    (azimuth about the y axis, elevation upwards) and frames the whole volume.
    """),
    code("""
    cam = hevr.Camera.orbit(ev, azimuth=AZIMUTH, elevation=ELEVATION, width=WIDTH, height=HEIGHT)
    print(cam)
    """),
    md("""
    ## 6. Render on the server

    `hevr.render` builds one Dask graph: a *map* task per brick sums the weighted
    ciphertexts along every ray (homomorphic additions and plaintext multiplications
    only), a *reduce* merges the partial sums per image tile, and a final per-pixel step
    divides by the number of samples. X-ray mode gives the mean value along each ray.
    The secret key is never involved.
    """),
    code("""
    img = hevr.render(ev, cam, mode="xray", sampling=SAMPLING, step=STEP, progress=False)
    print(img)
    print("stats:", img.stats)
    """),
    md("""
    ## 7. Back at the client: decrypt

    The encrypted image travels back as a compact `.hevr` file (many pixels are packed
    into each ciphertext). Only the private key with the matching fingerprint decrypts it;
    any other key raises `hevr.KeyMismatchError`.
    """),
    code("""
    frame_path = os.path.join(WORKDIR, "frame.hevr")
    img.save(frame_path)
    print(f"{frame_path}: {os.path.getsize(frame_path) / 1e3:.1f} kB, {img.n_ciphertexts} ciphertexts")

    received = hevr.load_image(frame_path)
    decrypted = received.decrypt(priv)
    hevr.save_png(decrypted, os.path.join(WORKDIR, "frame.png"))
    print("decrypted image:", decrypted.shape, decrypted.dtype,
          f"range {decrypted.min():.3f} .. {decrypted.max():.3f}")
    """),
    md("""
    ## 8. Compare with the plaintext reference

    `hevr.render_plain` renders the *unencrypted* volume with the same camera and
    sampling. The encrypted pipeline works with fixed-point numbers (trilinear weights
    with 3 decimals, a 4-digit reciprocal), so the two differ slightly;
    `hevr.rendering.encrypted.error_bound` gives the guaranteed per-pixel bound.
    """),
    code("""
    reference = hevr.render_plain(vol, cam, mode="xray", sampling=SAMPLING, step=STEP)
    difference = decrypted - reference
    bound = error_bound(ev, cam, mode="xray", sampling=SAMPLING, step=STEP)
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
    """),
    md("""
    ## 9. Clean up

    Close the client and the cluster, then remove the temporary folder (unless
    `KEEP_FILES`).
    """),
    code("""
    client.close()
    cluster.close()
    if not KEEP_FILES:
        shutil.rmtree(WORKDIR, ignore_errors=True)
    """),
    code("""
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
    """, "summary"),
]


# ---------------------------------------------------------------------------------------
# 02 transfer functions
# ---------------------------------------------------------------------------------------

TRANSFER = [
    md("""
    # Emphasis and transfer functions on an encrypted volume

    This notebook reproduces, on the encrypted phantom, the two result figures of
    Mazza, Patel & Viola (TVCG 2020):

    * the **emphasis figure**: an X-ray image, then the same view emphasising the
      normalised densities 0.653, 0.331 and 0.781 (the small sphere, the large sphere and
      the cube of the phantom);
    * the **colour figure**: four transfer functions (TFs), each a list of
      *(density, colour)* nodes.

    Every encrypted image is shown above its plaintext reference (`hevr.render_plain`).
    Finally a small widget re-colours the view interactively: since emphasis and TF modes
    are *linear* in the stored density encoding, the server keeps the per-view encrypted
    ray sums (`render(..., cache=True)`, the default) and a new density or colour only
    redoes the cheap per-pixel step.

    Sizes are deliberately small (24³ phantom, 40×40 images, 512-bit key); change them in
    the next cell.
    """),
    code("""
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

    # The paper's emphasis figure: X-ray plus these emphasised densities.
    EMPHASIS_DENSITIES = [0.653, 0.331, 0.781]

    # The paper's colour figure. Colours are (r, g, b) in [0, 1], '#rrggbb' or CSS names
    # (hevr.rendering.modes.parse_color); note that CSS "green" and "purple" are half-intensity
    # (0, 0.5, 0) and (0.5, 0, 0.5) - use "lime" or (0, 1, 0) for pure green.
    TRANSFER_FUNCTIONS = {
        "blue 0.279, red 0.797": [(0.279, "blue"), (0.797, "red")],
        "blue 0.000, red 1.000": [(0.000, "blue"), (1.000, "red")],
        "green 0.076, blue 0.651, red 1.000": [(0.076, "green"), (0.651, "blue"), (1.000, "red")],
        "blue 0.000, yellow 0.293, green 0.664, purple 1.000":
            [(0.000, "blue"), (0.293, "yellow"), (0.664, "green"), (1.000, "purple")],
    }
    """, "parameters"),
    code("""
    import json
    import os
    import shutil
    import tempfile
    import textwrap
    import time
    import warnings

    import ipywidgets as widgets
    import matplotlib.pyplot as plt
    import numpy as np
    from distributed import Client, LocalCluster
    from IPython.display import display

    import hevr
    from hevr.image import to_uint8
    from hevr.rendering.modes import CSS_COLORS, parse_color
    from hevr.rendering.encrypted import error_bound

    WORKDIR = tempfile.mkdtemp(prefix="hevr-tf-")
    """),
    md("""
    ## 1. Owner: keys and encrypted volume; server: a local cluster

    The same steps as in `01_quickstart.ipynb`. `vector_dims=4` stores, next to the scalar
    channel used by X-ray, the 4-dimensional density encoding that emphasis and TFs need.
    (The `InsecureKeyWarning` for the 512-bit demo key is silenced on purpose.)
    """),
    code("""
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
    print(ev)
    print("phantom density levels:", hevr.PHANTOM_LEVELS)
    """),
    md("""
    ## 2. Render, decrypt, compare

    `render_and_check` renders on the server, decrypts on the client, renders the
    plaintext reference and asserts that every pixel is within the guaranteed error bound
    (`hevr.rendering.encrypted.error_bound`). It also records the render statistics: `map_tasks` is
    the number of per-brick tasks that ran (0 when the cached ray sums were reused).
    """),
    code("""
    results = []   # one row per rendered image

    def render_and_check(mode, label, **params):
        t0 = time.perf_counter()
        img = hevr.render(ev, cam, mode=mode, sampling=SAMPLING, step=STEP, progress=False, **params)
        seconds = time.perf_counter() - t0
        enc = img.decrypt(priv)
        ref = hevr.render_plain(vol, cam, mode=mode, sampling=SAMPLING, step=STEP,
                                vector_dims=VECTOR_DIMS, **params)
        bound = error_bound(ev, cam, mode=mode, sampling=SAMPLING, step=STEP, **params)
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
            print(f"{r['label']:56s} {r['map_tasks']:9d} {str(r['reused_ray_sums']):>6s} "
                  f"{r['seconds']:7.2f} {r['max_error']:9.2g} {r['bound']:9.2g}")
    """),
    md("""
    ## 3. The emphasis figure

    X-ray averages the scalar channel along each ray. Emphasis averages
    `dot(s, e(density))`, where `s` is the sampled encoded vector and `e` the density
    encoding: voxels whose density is close to the emphasised one light up. The first
    emphasis image computes the encrypted ray sums of the vector channel; the next two
    reuse them (`map_tasks == 0`).
    """),
    code("""
    emphasis = [render_and_check("xray", "X-ray")]
    for d in EMPHASIS_DENSITIES:
        emphasis.append(render_and_check("emphasize", f"emphasis {d:.3f}", density=d))
    print_rows([row for _, _, row in emphasis])

    fig, axes = plt.subplots(2, len(emphasis), figsize=(2.6 * len(emphasis), 5.4), squeeze=False)
    for j, (enc, ref, row) in enumerate(emphasis):
        vmax = max(float(ref.max()), 1e-12)
        for i, (arr, kind) in enumerate(((enc, "encrypted"), (ref, "plaintext"))):
            axes[i, j].imshow(arr, cmap="gray", vmin=0, vmax=vmax)
            axes[i, j].set_title(f"{row['label']}\\n{kind}", fontsize=9)
            axes[i, j].axis("off")
    fig.suptitle("Emphasis figure: encrypted render (top) vs plaintext reference (bottom)")
    plt.tight_layout()
    plt.show()
    """),
    md("""
    ## 4. The colour figure

    A TF with nodes *(d_i, c_i)* averages `Σ_i dot(s, e(d_i))·c_i / K` along each ray, an
    RGB image. All four TFs reuse the ray sums cached for the emphasis images. Each
    encrypted image and its reference share one display window (0 to the reference's
    maximum, jointly over the channels) so colours are comparable.
    """),
    code("""
    colour = []
    for label, nodes in TRANSFER_FUNCTIONS.items():
        nodes = [(d, parse_color(c)) for d, c in nodes]
        colour.append(render_and_check("tf", "TF " + label, nodes=nodes))
    print_rows([row for _, _, row in colour])

    fig, axes = plt.subplots(2, len(colour), figsize=(3.0 * len(colour), 6.4), squeeze=False)
    for j, (enc, ref, row) in enumerate(colour):
        window = (0.0, max(float(ref.max()), 1e-12))
        for i, (arr, kind) in enumerate(((enc, "encrypted"), (ref, "plaintext"))):
            axes[i, j].imshow(to_uint8(arr, window))
            title = "\\n".join(textwrap.wrap(row["label"][len("TF "):], 28))
            axes[i, j].set_title(f"{title}\\n{kind}", fontsize=8)
            axes[i, j].axis("off")
    fig.suptitle("Colour figure: encrypted render (top) vs plaintext reference (bottom)")
    plt.tight_layout()
    plt.show()
    """),
    md("""
    ## 5. Interactive re-colouring from the cached ray sums

    Pick a density with the slider (it re-renders when released: `continuous_update=False`)
    and a colour, or press **re-colour**. The callback renders a one-node TF
    *(density, colour)* for the same camera, so the server skips the per-brick work
    entirely: the statistics show `reused_ray_sums=True` and `map_tasks=0`.

    Widgets need a live Jupyter front end; when the notebook runs headless (as in the
    test suite) they do not display, so the cell after next also calls the callback
    programmatically.
    """),
    code("""
    density_slider = widgets.FloatSlider(value=0.653, min=0.0, max=1.0, step=0.001,
                                         readout_format=".3f", description="density",
                                         continuous_update=False)
    colour_picker = widgets.Dropdown(options=sorted(CSS_COLORS), value="red", description="colour")
    recolour_button = widgets.Button(description="re-colour", icon="paint-brush")
    view = widgets.Output()
    last_recolour = {}   # statistics of the latest callback, for inspection below

    def recolour(_event=None):
        density, colour_name = density_slider.value, colour_picker.value
        nodes = [(density, parse_color(colour_name))]
        t0 = time.perf_counter()
        img = hevr.render(ev, cam, mode="tf", nodes=nodes, sampling=SAMPLING, step=STEP, progress=False)
        enc = img.decrypt(priv)
        seconds = time.perf_counter() - t0
        ref = hevr.render_plain(vol, cam, mode="tf", nodes=nodes, sampling=SAMPLING, step=STEP,
                                vector_dims=VECTOR_DIMS)
        last_recolour.clear()
        last_recolour.update(density=density, colour=colour_name, seconds=round(seconds, 3),
                             reused_ray_sums=img.stats["reused_ray_sums"],
                             map_tasks=img.stats["map_tasks"],
                             max_error=float(np.abs(enc - ref).max()))
        with view:
            view.clear_output(wait=True)
            fig, ax = plt.subplots(figsize=(3, 3))
            ax.imshow(to_uint8(enc, (0.0, max(float(ref.max()), 1e-12))))
            ax.set_title(f"{colour_name} at {density:.3f}", fontsize=9)
            ax.axis("off")
            plt.show()
            print(f"reused_ray_sums={img.stats['reused_ray_sums']}, map_tasks={img.stats['map_tasks']}, "
                  f"render + decrypt {seconds:.2f} s")

    recolour_calls = []
    def on_recolour(event=None):
        recolour_calls.append(event)
        recolour(event)
        last_recolour["calls"] = len(recolour_calls)

    recolour_button.on_click(on_recolour)
    density_slider.observe(on_recolour, names="value")
    display(widgets.VBox([widgets.HBox([density_slider, colour_picker, recolour_button]), view]))
    """),
    code("""
    # Drive the widgets from code (what a click would do), then inspect the result.
    colour_picker.value = "lime"
    recolour_button.click()
    print("after the click:", last_recolour)
    assert last_recolour["reused_ray_sums"] is True and last_recolour["map_tasks"] == 0

    density_slider.value = 0.331   # moving the slider re-renders too
    print("after the slider:", last_recolour)
    assert last_recolour["reused_ray_sums"] is True and last_recolour["map_tasks"] == 0
    assert abs(last_recolour["density"] - 0.331) < 1e-9 and last_recolour["calls"] == 2
    """),
    md("""
    ## 6. Clean up
    """),
    code("""
    client.close()
    cluster.close()
    shutil.rmtree(WORKDIR, ignore_errors=True)
    """),
    code("""
    # Summary of this run (read by tests/test_notebooks.py).
    summary = {
        "images": [{k: r[k] for k in ("label", "map_tasks", "reused_ray_sums", "max_error", "bound")}
                   for r in results],
        "recolour": last_recolour,
    }
    print(json.dumps(summary))
    """, "summary"),
]


# ---------------------------------------------------------------------------------------
# 03 scaling
# ---------------------------------------------------------------------------------------

SCALING = [
    md("""
    # Scaling: workers, brick size and key size

    Three small experiments on the encrypted phantom:

    * **(a) workers** - the same render on a 1-worker and a 2-worker `LocalCluster`
      (speed-up);
    * **(b) brick size** - encryption time, render time and number of map tasks for
      several brick edges;
    * **(c) key size** - owner-side encryption time per voxel, render time and decryption
      time for several Paillier key sizes.

    The defaults finish in well under a minute on 2 cores. All sizes are parameters in the
    next cell: scale them up (e.g. `PHANTOM_SIZE = 100`, `KEY_SIZES = [1024, 2048]`,
    `WORKER_COUNTS = [1, 2, 4, 8]`) on a bigger machine. Timings on a shared machine are
    noisy: each render is repeated `REPEATS` times and the fastest run is reported.
    """),
    code("""
    # --- parameters --------------------------------------------------------------------
    PHANTOM_SIZE = 24
    SAMPLING = "trilinear"
    AZIMUTH, ELEVATION = 30, 20
    REPEATS = 2                 # timed repetitions per render (the minimum is reported)

    # (a) workers: one render, timed on a cluster scaled to each of these sizes (ascending)
    WORKER_COUNTS = [1, 2]
    A_KEY_BITS = 512
    A_BRICK = 8
    A_IMAGE = 64                # pixels per side
    A_MODE, A_DENSITY = "emphasize", 0.653   # the vector modes do the most work per brick

    # (b) brick size, and (c) key size: run on one cluster of N_WORKERS workers
    N_WORKERS = 2
    IMAGE = 40
    BRICK_SIZES = [6, 8, 12]
    B_KEY_BITS = 512
    KEY_SIZES = [256, 512, 1024]
    C_BRICK = 12
    RAW_ENCRYPTIONS = 100       # ciphertexts for the single-core per-value timing in (c)
    VECTOR_DIMS_BC = None       # None: scalar channel only (X-ray); 4 adds the density encoding
    """, "parameters"),
    code("""
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
    from hevr.rendering.encrypted import error_bound

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
        \"\"\"Scale the cluster to exactly n workers and wait until they are there.\"\"\"
        cluster.scale(n)
        t0 = time.perf_counter()
        while len(client.nthreads()) != n:
            if time.perf_counter() - t0 > timeout:
                raise TimeoutError(f"cluster did not reach {n} workers in {timeout} s")
            time.sleep(0.1)

    def timed_render(ev, cam, repeats=REPEATS, **kw):
        \"\"\"Fastest of `repeats` renders (cache=False: every run does the full map-reduce).\"\"\"
        best, img = math.inf, None
        for _ in range(repeats):
            t0 = time.perf_counter()
            img = hevr.render(ev, cam, sampling=SAMPLING, progress=False, cache=False, **kw)
            best = min(best, time.perf_counter() - t0)
        return best, img

    def check(ev, cam, img, priv, **kw):
        \"\"\"Decrypt and assert the image is within the error bound of the plaintext render.\"\"\"
        enc = img.decrypt(priv)
        ref = hevr.render_plain(vol, cam, sampling=SAMPLING, vector_dims=ev.vector_dims, **kw)
        bound = error_bound(ev, cam, sampling=SAMPLING, **kw)
        assert (np.abs(enc - ref) <= bound).all()
        return enc
    """),
    md("""
    ## (a) 1 vs 2 workers

    The volume is encrypted once (on Dask's default scheduler, before any cluster
    exists). Then one `LocalCluster` is started with `WORKER_COUNTS[0]` workers and scaled
    up step by step; at each size every worker is warmed up (hevr imported, one tiny
    render) before the render is timed.
    """),
    code("""
    pub_a, priv_a = hevr.generate_keypair(A_KEY_BITS)
    ev_a = hevr.encrypt_volume(vol, os.path.join(WORKDIR, "a.zarr"), priv_a, brick=A_BRICK,
                               vector_dims=4, progress=False)
    cam_a = hevr.Camera.orbit(ev_a, azimuth=AZIMUTH, elevation=ELEVATION, width=A_IMAGE, height=A_IMAGE)
    warm_cam = hevr.Camera.orbit(ev_a, azimuth=AZIMUTH, elevation=ELEVATION, width=8, height=8)

    def warm_up():
        import hevr.rendering.encrypted  # noqa: F401  (runs on every worker)

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
    """),
    md("""
    ## (b) Brick size

    Each brick is one encryption task and one map task of the render. Small bricks give
    more parallelism but more per-task overhead (and rays are split into more partial
    sums to merge); large bricks give few, long tasks. The cluster is resized to
    `N_WORKERS` workers for the remaining experiments.
    """),
    code("""
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
    """),
    md("""
    ## (c) Key size

    Paillier ciphertexts are numbers modulo *n*², so every operation gets slower as the
    key grows (roughly cubically for exponentiations). We measure

    * owner-side encryption: `encrypt_volume` with the private key (fast CRT path, run on
      the cluster) per voxel, plus single-core `priv.encrypt_array` (owner fast path) and
      `pub.encrypt_array` (public key only) per value;
    * the render (server) and the decryption (client) of one X-ray image.
    """),
    code("""
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
    """),
    md("""
    ## Clean up
    """),
    code("""
    client.close()
    cluster.close()
    shutil.rmtree(WORKDIR, ignore_errors=True)
    print(f"total {time.perf_counter() - NOTEBOOK_T0:.1f} s")
    """),
    code("""
    # Summary of this run (read by tests/test_notebooks.py).
    summary = {
        "worker_seconds": {str(n): round(s, 3) for n, s in worker_seconds.items()},
        "speedup": {str(n): round(s, 3) for n, s in speedups.items()},
        "bricks": brick_rows,
        "brick_images_identical": identical,
        "keys": key_rows,
    }
    print(json.dumps(summary))
    """, "summary"),
]


NOTEBOOKS = {
    "01_quickstart": QUICKSTART,
    "02_transfer_functions": TRANSFER,
    "03_scaling": SCALING,
}


def build() -> dict[str, str]:
    """Notebook file name -> JSON text (what would be written)."""
    return {f"{stem}.ipynb": nbformat.writes(make_notebook(stem, cells)) + "\n"
            for stem, cells in NOTEBOOKS.items()}


def main(argv: list[str]) -> int:
    check = "--check" in argv
    stale = []
    for name, text in build().items():
        path = HERE / name
        if check:
            if not path.exists() or path.read_text(encoding="utf-8") != text:
                stale.append(name)
        else:
            path.write_text(text, encoding="utf-8")
            print("wrote", path)
    if stale:
        print("out of date (run python notebooks/_build.py):", ", ".join(stale), file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
