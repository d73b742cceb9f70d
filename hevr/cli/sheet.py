"""The demo's contact sheet: every decrypted render beside its plaintext reference."""

from __future__ import annotations

import io
import math
from pathlib import Path
from typing import Any

from PIL import Image, ImageDraw, ImageFont

from ..core.files import write_file

__all__ = ["contact_sheet", "drawable"]

_PAD = 8
_GAP = 4
_PAIRS_PER_ROW = 2
_MIN_EDGE = 160  # small renders are enlarged (nearest neighbour) to at least this size


def _font(size: int) -> Any:

    try:
        return ImageFont.load_default(size=size)
    except TypeError:  # Pillow < 10.1
        return ImageFont.load_default()


# Pillow's built-in font has no glyph for these: they would be drawn as boxes
_PLAIN = str.maketrans({"×": "x", "→": "->", "…": "...", "²": "^2", "³": "^3", "·": "*"})


def drawable(text: str) -> str:
    """``text`` in characters Pillow's built-in font draws.

    >>> drawable("phantom, x×y×z = 64×64×64 voxels, 150² px")
    'phantom, 64x64x64 voxels, 150^2 px'
    """
    return text.replace("x×y×z = ", "").replace("W×H = ", "").translate(_PLAIN)


def contact_sheet(folder: Path, jobs: list, caption: str, out: Path, *, overwrite: bool = False) -> None:
    """Lay out ``<name>.png`` | ``<name>.ref.png`` for every job, with a caption line each; written
    to ``out`` atomically, over an existing file only with ``overwrite``."""

    pairs = []
    for job in jobs:
        enc = Image.open(folder / f"{job.name}.png").convert("RGB")
        ref = Image.open(folder / f"{job.name}.ref.png").convert("RGB")
        pairs.append((job, enc, ref))
    w, h = pairs[0][1].size
    scale = max(1, math.ceil(_MIN_EDGE / max(w, h)))
    cw, ch = w * scale, h * scale
    font, small = _font(13), _font(11)
    line = 16
    cell_w = 2 * cw + _GAP
    cell_h = ch + 2 * line + _GAP
    cols = min(_PAIRS_PER_ROW, len(pairs))
    rows = math.ceil(len(pairs) / cols)
    width = _PAD + cols * (cell_w + _PAD)
    height = _PAD + line + _PAD + rows * (cell_h + _PAD)
    sheet = Image.new("RGB", (width, height), (255, 255, 255))
    draw = ImageDraw.Draw(sheet)
    draw.text((_PAD, _PAD), drawable(caption), fill=(0, 0, 0), font=font)
    for i, (job, enc, ref) in enumerate(pairs):
        r, c = divmod(i, cols)
        x = _PAD + c * (cell_w + _PAD)
        y = _PAD + line + _PAD + r * (cell_h + _PAD)
        res = job.result
        draw.text((x, y), drawable(job.title), fill=(0, 0, 0), font=small)
        draw.text(
            (x, y + line),
            f"max|err| {res['max_abs_error']:.1e}   render {res['render_s']:.2f} s   decrypt {res['decrypt_s']:.2f} s",
            fill=(90, 90, 90),
            font=small,
        )
        top = y + 2 * line + _GAP
        sheet.paste(enc.resize((cw, ch), Image.Resampling.NEAREST), (x, top))
        sheet.paste(ref.resize((cw, ch), Image.Resampling.NEAREST), (x + cw + _GAP, top))
    buf = io.BytesIO()
    sheet.save(buf, format="PNG")
    write_file(out, [buf.getbuffer()], overwrite=overwrite, doing="writing the contact sheet")
