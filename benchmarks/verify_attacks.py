"""A lying server against verified renders (issue 38): every attack × every way of asking.

Each attack starts from a verifiable store the owner encrypted at a path (so the key holder's known
stores, where this hevr has them, recorded it), changes it (or a frame file) as a server with write
access would — recomputing every keyless checksum and digest — and then asks for the frame:

* ``None``: ``hevr.render(ev, cam)`` (the default) and ``img.decrypt(key)``;
* ``None, new machine``: the same with an empty known-stores file (trust on first use);
* ``True``: ``verify=True``;
* ``pinned``: ``verify=<store id the owner recorded>``;
* ``CLI``: ``hevr render`` (with ``--key`` where this hevr has it: the key holder's process) then
  ``hevr decrypt``; for the file attacks, ``hevr decrypt`` of the file the server handed over.

Outcomes: ``refused`` (an error before any pixel was rendered), ``caught`` (a VerificationError or
IntegrityError at decryption), ``ACCEPTED verified`` / ``ACCEPTED, not verified`` (a wrong image
returned, with or without the "verified" label), ``verified (own view)`` for a genuinely verified
frame that the CLI shows with the store, view and level it proves. Written to run on older hevr
too (features it lacks are skipped), so that before and after come from one script::

    python benchmarks/verify_attacks.py --out benchmarks/results-verify-attacks.json
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import shutil
import sys
import tempfile
import warnings
from pathlib import Path

import dask
import numpy as np
import zarr

import hevr
from hevr.cli.main import main as cli
from hevr.image.header import MAGIC
from hevr.store.metadata import metadata_checksum

VOL = np.random.default_rng(7).integers(0, 256, (8, 8, 8)).astype(np.uint8)
OTHER = np.random.default_rng(8).integers(0, 256, (8, 8, 8)).astype(np.uint8)
M = len(MAGIC)
COLUMNS = ("None", "None, new machine", "True", "pinned", "CLI")


def encrypt(vol, path, priv, **kw):
    return hevr.encrypt_volume(vol, path, priv, brick=4, vector_dims=3, verifiable=True, progress=False, **kw)


def edit_meta(path, change):
    group = zarr.open_group(str(path), mode="r+")
    d = dict(group.attrs["hevr"])
    change(d)
    d["checksum"] = metadata_checksum(d)
    group.attrs["hevr"] = d


def strip_tags(path):
    def change(d):
        d.pop("tags", None)
        d.pop("auth", None)
        d["arrays"] = {k: v for k, v in d["arrays"].items() if not k.endswith("_tag")}

    edit_meta(path, change)
    for name in os.listdir(path):
        if name.endswith("_tag"):
            shutil.rmtree(Path(path) / name)


def camera(ev, azimuth=30):
    return hevr.Camera.orbit(ev, azimuth=azimuth, elevation=20, width=10, height=9)


def run_cli(*argv):
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = cli([str(a) for a in argv])
    return code, out.getvalue(), err.getvalue()


def outcome_of_decrypt(img, priv):
    try:
        img.decrypt(priv)
    except hevr.IntegrityError as exc:
        return "caught", str(exc)[:100]
    return ("ACCEPTED verified" if img.verification is not None else "ACCEPTED, not verified"), ""


def py_column(path, priv, verify, fresh_known=None):
    env = os.environ.get("HEVR_KNOWN_STORES")
    if fresh_known is not None:
        os.environ["HEVR_KNOWN_STORES"] = fresh_known
    try:
        ev = hevr.open_volume(path)
        img = hevr.render(ev, camera(ev), progress=False, cache=False, verify=verify)
    except hevr.HevrError as exc:
        return "refused", f"{type(exc).__name__}: {str(exc)[:100]}"
    finally:
        if env is not None:
            os.environ["HEVR_KNOWN_STORES"] = env
    return outcome_of_decrypt(img, priv)


def has_key_option():
    code, out, err = run_cli("render", "--help")
    return "--require-verified" in run_cli("decrypt", "--help")[1] or "--key" in out


def cli_column(path, key_file, tmp):
    frame = Path(tmp) / f"cli-{os.urandom(4).hex()}.hevr"
    extra = ["--key", key_file] if KEY_OPTION else []
    code, out, err = run_cli(
        "render", path, "--out", frame, "--size", "10x9", "--azimuth", "30", "--elevation", "20", "-q", *extra
    )
    if code:
        return "refused", err.strip()[:100]
    return cli_decrypt(frame, key_file, tmp)


def cli_decrypt(frame, key_file, tmp, *extra):
    png = Path(tmp) / f"{os.urandom(4).hex()}.png"
    code, out, err = run_cli("decrypt", frame, "--key", key_file, "--out", png, *extra)
    if code:
        return "caught", err.strip()[:100]
    line = next((x for x in out.splitlines() if x.startswith(("verified", "not verified"))), "")
    return ("ACCEPTED verified" if line.startswith("verified") else "ACCEPTED, not verified"), line[:160]


def store_attacks(tmp, priv, key_file):
    """Attacks on the store: (name, how it changes the store at the path)."""

    def meta(change):
        return lambda p: edit_meta(p, change)

    def spacing(d, f):
        d["spacing"] = [s * x for s, x in zip(d["spacing"], f)]

    def another_store(p):
        q = Path(tmp) / f"other-{os.urandom(3).hex()}.zarr"
        encrypt(OTHER, q, priv)
        shutil.rmtree(p)
        shutil.copytree(q, p)

    def older_version(p):
        old = Path(tmp) / f"old-{os.urandom(3).hex()}.zarr"
        shutil.copytree(p, old)
        sid = encrypt(OTHER, p, priv, overwrite=True).meta.store_id  # the owner re-encrypts (new data) ...
        shutil.rmtree(p)
        shutil.copytree(old, p)  # ... and the server serves the old version
        return sid  # the id the owner now pins

    def without_tags(p):  # the server encrypts other values with the public key: a store without tags
        q = Path(tmp) / f"plain-{os.urandom(3).hex()}.zarr"
        hevr.encrypt_volume(OTHER, q, priv.public_key, brick=4, vector_dims=3, progress=False)
        shutil.rmtree(p)
        shutil.copytree(q, p)

    def exponent(d):
        d["channels"]["scalar"]["exponent"] = -3

    def digits(d):
        v = d["channels"]["vector"]
        v["digits"], v["exponent"] = v["digits"] + 1, v["exponent"] - 1
        d["channels"]["gradient"] = v if "gradient" in d["channels"] else None
        d["channels"] = {k: x for k, x in d["channels"].items() if x is not None}

    def value_range(d):
        d["value_range"] = [0.0, 25.5]

    return [
        ("metadata: spacing ×2", meta(lambda d: spacing(d, (2, 2, 2)))),
        ("metadata: anisotropic spacing", meta(lambda d: spacing(d, (1, 1, 3)))),
        ("metadata: exponent 0 → −3", meta(exponent)),
        ("metadata: digits +1 (colours ÷10)", meta(digits)),
        ("metadata: value range", meta(value_range)),
        ("replaced by a store without tags", without_tags),
        ("another verifiable store of the key", another_store),
        ("older version of the store", older_version),
    ]


def file_attacks(tmp, priv, key_file, path):
    """Attacks on frame files: (name, the file the server hands over instead of the one asked for)."""
    ev = hevr.open_volume(path)
    asked = camera(ev)

    def verified(cam, level=None, where=None):
        img = hevr.render(where or ev, cam, progress=False, cache=False, level=level)
        f = Path(tmp) / f"v-{os.urandom(4).hex()}.hevr"  # each frame under its own name
        try:
            img.save(f, private_key=priv)
        except TypeError:  # an hevr without stamps
            img.save(f)
        return f, img

    out = []
    f, _ = verified(camera(ev, 60))
    out.append(("file: another camera's verified frame", f))
    q = Path(tmp) / f"q-{os.urandom(3).hex()}.zarr"
    evq = encrypt(OTHER, q, priv)
    f, _ = verified(camera(evq), where=evq)
    out.append(("file: another store's verified frame", f))
    pyr = Path(tmp) / f"pyr-{os.urandom(3).hex()}.zarr"
    evp = encrypt(VOL, pyr, priv)
    hevr.build_pyramid(evp, levels=1, progress=False)
    evp = hevr.open_volume(pyr)
    f, _ = verified(camera(evp), level=1, where=evp)
    out.append(("file: a level-1 frame for level 0", f))
    re = Path(tmp) / f"re-{os.urandom(3).hex()}.zarr"
    ev_old = encrypt(VOL, re, priv)
    f_old, _ = verified(camera(ev_old), where=ev_old)
    encrypt(OTHER, re, priv, overwrite=True)
    out.append(("file: an old frame replayed after re-encryption", f_old))
    f, img = verified(asked)
    raw = bytearray(f.read_bytes())
    head_len = int.from_bytes(raw[M : M + 4], "little")
    head = json.loads(raw[M + 4 : M + 4 + head_len])
    head["exponent"] -= 3
    head["verification"]["exponent"] -= 3
    out.append(("file: header and record exponent raised", _rewrite(tmp, raw, head, head_len)))
    head = json.loads(raw[M + 4 : M + 4 + head_len])
    head.pop("stamp", None)
    head.pop("saved_as", None)
    out.append(("file: a record without the key holder's stamp", _rewrite(tmp, raw, head, head_len)))
    head = json.loads(raw[M + 4 : M + 4 + head_len])
    head.pop("verification")
    head.pop("stamp", None)
    head.pop("saved_as", None)
    out.append(("file: the record removed", _rewrite(tmp, raw, head, head_len)))
    return out


def _rewrite(tmp, raw, head, head_len):
    import hashlib

    text = json.dumps(head, separators=(",", ":")).encode()
    body = bytes(raw[:M]) + len(text).to_bytes(4, "little") + text + bytes(raw[M + 4 + head_len : -32])
    f = Path(tmp) / f"edit-{os.urandom(4).hex()}.hevr"
    f.write_bytes(body + hashlib.sha256(body).digest())
    return f


def table(before: str, after: str) -> str:
    """A markdown table of two runs' outcomes (``before → after`` per attack and column)."""
    b, a = (json.loads(Path(p).read_text()) for p in (before, after))
    cols = ("None", "None, new machine", "True", "pinned", "CLI", "CLI --require-verified")
    lines = [
        f"Before: hevr {b.get('commit') or '?'}; after: hevr {a.get('commit') or '?'}. Cell: before → after.",
        "",
        "| attack | " + " | ".join(f"`{c}`" for c in cols) + " |",
        "|---" * (len(cols) + 1) + "|",
    ]
    old = {r["attack"]: r for r in b["rows"]}
    for r in a["rows"]:
        o = old.get(r["attack"], {})
        cells = [f"{o[c][0] if c in o else '—'} → {r[c][0]}" if c in r else "—" for c in cols]
        lines.append(f"| {r['attack']} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def main() -> int:
    global KEY_OPTION
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", help="write the results as JSON")
    ap.add_argument("--table", nargs=2, metavar=("BEFORE.json", "AFTER.json"), help="print the before/after table")
    args = ap.parse_args()
    if args.table:
        print(table(*args.table), end="")
        return 0
    warnings.simplefilter("ignore")
    rows = []
    with tempfile.TemporaryDirectory() as tmp, dask.config.set(scheduler="sync"):
        os.environ["HEVR_KNOWN_STORES"] = str(Path(tmp) / "known.json")
        os.environ["DASK_HEVR__JOURNAL_DIR"] = str(Path(tmp) / "journals")
        key_file = Path(tmp) / "key.json"
        run_cli("keygen", "--bits", "256", "--out", key_file, "-q")
        priv = hevr.load_key(key_file)
        KEY_OPTION = has_key_option()
        for name, attack in store_attacks(tmp, priv, key_file):
            path = Path(tmp) / f"s-{os.urandom(3).hex()}.zarr"
            sid = encrypt(VOL, path, priv).meta.store_id
            sid = attack(path) or sid
            row = {"attack": name}
            for col, verify, fresh in (
                ("None", None, None),
                ("None, new machine", None, str(Path(tmp) / "fresh.json")),
                ("True", True, None),
                ("pinned", sid, None),
            ):
                if fresh and os.path.exists(fresh):
                    os.remove(fresh)
                row[col] = py_column(path, priv, verify, fresh)
            row["CLI"] = cli_column(path, key_file, tmp)
            rows.append(row)
            print(f"{name:48s} " + " | ".join(row[c][0] for c in COLUMNS), flush=True)
        path = Path(tmp) / "asked.zarr"
        encrypt(VOL, path, priv)
        for name, given in file_attacks(tmp, priv, key_file, path):
            f = Path(tmp) / os.urandom(4).hex() / "frame.hevr"  # the name the key holder saved its frame as
            f.parent.mkdir()
            shutil.copyfile(given, f)
            try:
                py = outcome_of_decrypt(hevr.load_image(f), priv)
            except hevr.HevrError as exc:
                py = ("caught", str(exc)[:100])
            row = {"attack": name, "None": py, "CLI": cli_decrypt(f, key_file, tmp)}
            if KEY_OPTION:
                row["CLI --require-verified"] = cli_decrypt(f, key_file, tmp, "--require-verified")
            rows.append(row)
            req = row.get("CLI --require-verified", ("-",))[0]
            print(
                f"{name:48s} {row['None'][0]} | CLI: {row['CLI'][0]} | --require-verified: {req}: {row['CLI'][1][:90]}",
                flush=True,
            )
    if args.out:
        Path(args.out).write_text(
            json.dumps({"hevr": hevr.__version__, "commit": os.environ.get("COMMIT", ""), "rows": rows}, indent=1)
            + "\n"
        )
    return 0


KEY_OPTION = False

if __name__ == "__main__":
    sys.exit(main())
