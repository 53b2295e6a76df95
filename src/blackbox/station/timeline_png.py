"""The health timeline as a PNG, drawn without a browser: for an incident report written
where only the robot's own log is at hand (``blackbox log export --timeline -o t.png``).

It draws the same lanes as :func:`blackbox.station.timeline.svg`, with the same geometry
and colours, at ``scale`` times its size (2 by default, like the page's PNG export), with
Pillow (already installed with matplotlib) and its bundled font, so no system library or
browser is needed.
"""

from __future__ import annotations

import io
from collections.abc import Sequence

from PIL import Image, ImageDraw, ImageFont

from blackbox.station.timeline import COLOURS, LABEL_WIDTH, LANE_HEIGHT, TOP, WIDTH, Lane, clock

INK, MUTED, ACK = "#1f2328", "#656d76", "#1f2328"


def png(lanes: Sequence[Lane], start: float, end: float, *, scale: int = 2) -> bytes:
    """The picture as PNG bytes, ``scale`` device pixels per SVG pixel."""
    window = max(end - start, 1e-9)
    plot = WIDTH - LABEL_WIDTH - 10
    height = TOP + LANE_HEIGHT * len(lanes) + 6
    image = Image.new("RGB", (WIDTH * scale, height * scale), "#ffffff")
    draw = ImageDraw.Draw(image)
    font = _font(12 * scale)

    def x(t: float) -> float:
        return (LABEL_WIDTH + (t - start) / window * plot) * scale

    for i in range(5):
        t = start + window * i / 4
        anchor = "ls" if i == 0 else ("rs" if i == 4 else "ms")
        _text(draw, (x(t), 14 * scale), clock(t, window), MUTED, font, anchor)
    for row, lane in enumerate(lanes):
        y = TOP + row * LANE_HEIGHT
        label = lane.entity if len(lane.entity) <= 28 else "…" + lane.entity[-27:]
        _text(draw, (4 * scale, (y + LANE_HEIGHT - 6) * scale), label, INK, font, "ls")
        for span in lane.spans:
            left, right = x(span.start), max(x(span.end), x(span.start) + 0.5 * scale)
            draw.rectangle((left, (y + 3) * scale, right - 1, (y + LANE_HEIGHT - 3) * scale - 1),
                           fill=COLOURS.get(span.status, COLOURS["UNKNOWN"]))
        for mark in lane.marks:
            mx = x(mark.time)
            if mark.kind == "acknowledged":
                bottom = (y + LANE_HEIGHT - 1) * scale
                draw.polygon([(mx - 4 * scale, bottom), (mx, bottom - 6 * scale),
                              (mx + 4 * scale, bottom)], fill=ACK)
            else:
                draw.rectangle((mx - 1 * scale, y * scale, mx + 1 * scale - 1,
                                (y + LANE_HEIGHT) * scale - 1), fill=COLOURS["DEGRADED"])
    out = io.BytesIO()
    image.save(out, format="PNG", optimize=True)
    return out.getvalue()


def _text(draw: ImageDraw.ImageDraw, at: tuple[float, float], text: str, fill: str,
          font: ImageFont.FreeTypeFont | ImageFont.ImageFont, anchor: str) -> None:
    """Text placed by its baseline like the SVG's (a bitmap font cannot be anchored)."""
    if isinstance(font, ImageFont.FreeTypeFont):
        draw.text(at, text, fill=fill, font=font, anchor=anchor)
    else:
        draw.text((at[0], at[1] - 10), text, fill=fill, font=font)


def _font(size: int) -> ImageFont.FreeTypeFont | ImageFont.ImageFont:
    """Pillow's bundled scalable font; its small bitmap font where FreeType is missing."""
    try:
        return ImageFont.load_default(size=size)
    except (ImportError, OSError, TypeError):
        return ImageFont.load_default()
