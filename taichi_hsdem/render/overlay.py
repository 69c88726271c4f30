"""What a micromodel's video adds to each frame (:class:`~.video.VideoRecorder`):
a red bar across every clogged throat and, in the top-left corner of the domain
(over the inlet, in a smaller font than the strip's), the pressure drop the pump
reads and the count of clogged throats. Painted into
the frame :meth:`~.frame.Renderer.draw` returned (numpy, on the host), so the
renderer itself is unchanged.

>>> import numpy as np
>>> frame = np.zeros((20, 40, 3), dtype=np.uint8)
>>> paint_segments(frame, np.array([[[5.0, 10.0], [35.0, 10.0]]]), 2.0, CLOG_RED)
>>> frame[10, 20].tolist(), frame[2, 20].tolist()
([230, 30, 30], [0, 0, 0])
"""
import numpy as np

from .font import GLYPH_H, stamp, text_mask

#: A clogged throat's bar; red is in neither the pressure map nor the species'
#: fills' range of lightness, and it is drawn over the particles.
CLOG_RED = (230, 30, 30)
LABEL_BACKGROUND = (24, 24, 24)
LABEL_TEXT = (235, 235, 235)


def paint_segments(frame, segments, half_width, colour) -> None:
    """Paint every pixel of ``frame`` (rows, cols, 3) whose centre lies within
    ``half_width`` pixels of one of ``segments`` (S, 2, 2) given in (col, row)
    pixel coordinates (``Renderer.world_to_pixel``)."""
    rows, cols = frame.shape[:2]
    for (c0, r0), (c1, r1) in np.asarray(segments, dtype=float):
        lo_c = max(0, int(np.floor(min(c0, c1) - half_width)))
        hi_c = min(cols, int(np.ceil(max(c0, c1) + half_width)) + 1)
        lo_r = max(0, int(np.floor(min(r0, r1) - half_width)))
        hi_r = min(rows, int(np.ceil(max(r0, r1) + half_width)) + 1)
        if lo_c >= hi_c or lo_r >= hi_r:
            continue
        pc, pr = np.meshgrid(np.arange(lo_c, hi_c) + 0.5, np.arange(lo_r, hi_r) + 0.5)
        dc, dr = c1 - c0, r1 - r0
        length2 = dc * dc + dr * dr
        t = np.clip(((pc - c0) * dc + (pr - r0) * dr) / length2, 0.0, 1.0) if length2 else 0.0
        near = np.hypot(pc - (c0 + t * dc), pr - (r0 + t * dr)) <= half_width
        frame[lo_r:hi_r, lo_c:hi_c][near] = colour


def paint_label(frame, text, scale) -> None:
    """``text`` in the top-left corner of ``frame`` on a dark box."""
    mask = text_mask(text, scale)
    pad = 2 * scale
    h = min(frame.shape[0], GLYPH_H * scale + 2 * pad)
    w = min(frame.shape[1], mask.shape[1] + 2 * pad)
    frame[:h, :w] = LABEL_BACKGROUND
    stamp(frame, mask, pad, pad, LABEL_TEXT)


def network_label(clogged: int, throats: int, drop, unit: str) -> str:
    """``"dp 12.4 Pa  clogged 5/25"``: the pressure drop (none without fluid; no unit
    for a dimensionless scene) and the throats clogged of all.

    >>> network_label(5, 25, 12.43, "Pa"), network_label(0, 9, None, "")
    ('dp 12.4 Pa  clogged 5/25', 'clogged 0/9')
    """
    pressure = "" if drop is None else f"dp {drop:.3g}{' ' + unit if unit else ''}  "
    return f"{pressure}clogged {clogged}/{throats}"
