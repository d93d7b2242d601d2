"""Text burned into rendered frames with Pillow (which matplotlib brings) and matplotlib's DejaVu fonts.

A caption band above each frame holds the task, the curve, the verdict and the clock; a key band under a
filmstrip or video says what the balance markers are. A filmstrip is the captioned frames tiled in rows.
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import numpy as np

FONT_PX = 14
LINE_PX = 18  # line pitch of a caption or the key
PAD_PX = 4
CAPTION_LINES = 4
CAPTION_PX = CAPTION_LINES * LINE_PX + 2 * PAD_PX  # 80: a frame height plus this stays a multiple of 8 (video)
GAP_PX = 4  # between a filmstrip's panels and rows
WHITE = (255, 255, 255)
GREY = (170, 170, 170)
GREEN = (90, 220, 90)
RED = (255, 90, 80)
AMBER = (250, 180, 60)


@lru_cache(maxsize=4)
def _font(bold: bool = False):
    import matplotlib
    from PIL import ImageFont

    name = "DejaVuSans-Bold.ttf" if bold else "DejaVuSans.ttf"
    return ImageFont.truetype(str(Path(matplotlib.get_data_path()) / "fonts" / "ttf" / name), FONT_PX)


def fit(draw, text: str, font, width: int) -> str:
    """``text`` cut to ``width`` pixels, an ellipsis marking the cut."""
    if draw.textlength(text, font=font) <= width:
        return text
    while len(text) > 1 and draw.textlength(text + "…", font=font) > width:
        text = text[:-1]
    return text + "…"


def caption(img: np.ndarray, lines: list[tuple[str, tuple[int, int, int], bool]]) -> np.ndarray:
    """``img`` (H, W, 3 uint8) under a black band of ``CAPTION_PX`` holding ``lines`` (text, colour, bold),
    each cut to the frame's width."""
    from PIL import Image, ImageDraw

    band = Image.new("RGB", (img.shape[1], CAPTION_PX), (0, 0, 0))
    draw = ImageDraw.Draw(band)
    for i, (text, color, bold) in enumerate(lines[:CAPTION_LINES]):
        font = _font(bold)
        draw.text((PAD_PX, PAD_PX + i * LINE_PX), fit(draw, text, font, img.shape[1] - 2 * PAD_PX), fill=color,
                  font=font)
    return np.concatenate([np.asarray(band), img[..., :3]], axis=0)


#: The balance markers of cmrt.viz.render: (glyph, colour, what it is).
KEY = (("disc", (25, 205, 230), "CoM (sphere) and its ground point"),
       ("bar", (25, 205, 50), "reference CoM c_r = s + d(t)"),
       ("disc", (230, 25, 25), "CoP"))
FOOTPRINT_KEY = ("box", (240, 150, 25), "footprint of a step")
#: The reference CoM's line in Yu's mode says where that target comes from instead (cmrt.control.references).
YU_REFERENCE_TEXT = "reference CoM c_r (Yu eq. 3.2: the feet, GRF-weighted) + d(t)"


def key_band(width: int, footprints: bool = False, reference: str = "center") -> np.ndarray:
    """A black band ``width`` wide naming the markers (the reference CoM's as the ``reference`` mode makes it),
    wrapped to as many lines as it needs; its height is a multiple of 8 (a video's macro block)."""
    from PIL import Image, ImageDraw

    key = KEY if reference != "yu" else (KEY[0], (*KEY[1][:2], YU_REFERENCE_TEXT), KEY[2])
    items = key + ((FOOTPRINT_KEY,) if footprints else ())
    font = _font()
    probe = ImageDraw.Draw(Image.new("RGB", (1, 1)))
    placed, x, row = [], PAD_PX, 0
    for glyph, color, text in items:
        w = 16 + int(probe.textlength(text, font=font)) + 14
        if x > PAD_PX and x + w > width:
            x, row = PAD_PX, row + 1
        placed.append((x, row, glyph, color, fit(probe, text, font, width - x - 16 - PAD_PX)))
        x += w
    height = -(-((row + 1) * LINE_PX + 2 * PAD_PX) // 8) * 8
    band = Image.new("RGB", (width, height), (0, 0, 0))
    draw = ImageDraw.Draw(band)
    for x, row, glyph, color, text in placed:
        y = PAD_PX + row * LINE_PX
        if glyph == "disc":
            draw.ellipse((x + 1, y + 3, x + 11, y + 13), fill=color)
        elif glyph == "bar":
            draw.rectangle((x + 5, y + 1, x + 7, y + 15), fill=color)
        else:
            draw.rectangle((x, y + 5, x + 12, y + 11), fill=color)
        draw.text((x + 16, y), text, fill=WHITE, font=font)
    return np.asarray(band)


def tile(rows: list[list[np.ndarray]], footprints: bool = False, reference: str = "center") -> np.ndarray:
    """Captioned frames in rows (``GAP_PX`` apart, on white), the key under them."""
    h, w = rows[0][0].shape[:2]
    n_cols = max(len(r) for r in rows)
    width = n_cols * w + (n_cols - 1) * GAP_PX
    out = np.full((len(rows) * (h + GAP_PX), width, 3), 255, np.uint8)
    for r, row in enumerate(rows):
        for c, img in enumerate(row):
            out[r * (h + GAP_PX):r * (h + GAP_PX) + h, c * (w + GAP_PX):c * (w + GAP_PX) + w] = img[..., :3]
    return np.concatenate([out, key_band(width, footprints, reference)], axis=0)


def save_png(img: np.ndarray, out: Path) -> None:
    """Write ``img`` as a full-colour PNG (a palette of 256 would merge the markers' cyan and green)."""
    from PIL import Image

    Image.fromarray(img).save(out, format="PNG", optimize=True)
