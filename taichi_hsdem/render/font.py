"""A small built-in bitmap font for the text strip under each frame (the time, the
escapee count, the colour bar's range), stamped into numpy images."""
import numpy as np

GLYPH_W, GLYPH_H = 5, 7   # bitmap font cell, before scaling

# Bitmap font: 5x7 cells, one hex byte per row, bit 4 = leftmost column.

_FONT_HEX = {
    " ": "00000000000000", "0": "0E11131519110E", "1": "040C040404040E",
    "2": "0E11010204081F", "3": "1F02040201110E", "4": "02060A121F0202",
    "5": "1F101E0101110E", "6": "0608101E11110E", "7": "1F010204080808",
    "8": "0E11110E11110E", "9": "0E11110F01020C",
    "A": "0E11111F111111", "B": "1E11111E11111E", "C": "0E11101010110E",
    "D": "1C12111111121C", "E": "1F10101E10101F", "F": "1F10101E101010",
    "G": "0E11101711110F", "H": "1111111F111111",
    "I": "0E04040404040E", "J": "0702020202120C", "K": "11121418141211",
    "L": "1010101010101F", "M": "111B1515111111", "N": "11111915131111",
    "O": "0E11111111110E", "P": "1E11111E101010", "Q": "0E11111115120D",
    "R": "1E11111E141211", "S": "0F10100E01011E", "T": "1F040404040404",
    "U": "1111111111110E", "V": "11111111110A04", "W": "1111111515150A",
    "X": "11110A040A1111", "Y": "1111110A040404", "Z": "1F01020408101F",
    "a": "00000E010F110F", "b": "1010161911111E",
    "c": "00000E1010110E", "d": "01010D1311110F", "e": "00000E111F100E",
    "f": "0609081C080808", "g": "000F11110F010E", "h": "10101619111111",
    "i": "04000C0404040E", "j": "0200060202120C", "k": "10101214181412",
    "l": "0C04040404040E", "m": "00001A15151111", "n": "00001619111111",
    "o": "00000E1111110E", "p": "00001E111E1010", "q": "00000D130F0101",
    "r": "00001619101010", "s": "00000E100E011E", "t": "08081C08080906",
    "u": "0000111111130D", "v": "00001111110A04", "w": "0000111115150A",
    "x": "0000110A040A11", "y": "000011110F010E",
    "z": "00001F0204081F",
    ".": "00000000000C0C", ",": "000000000C0408",
    ":": "000C0C000C0C00", ";": "000C0C000C0408", "-": "0000001F000000",
    "+": "0004041F040400", "=": "00001F001F0000", "_": "0000000000001F",
    "/": "01010204081010", "(": "02040808080402", ")": "08040202020408",
    "[": "0E08080808080E", "]": "0E02020202020E", "%": "18190204081303",
    "!": "04040404040004", "?": "0E110102040004", "#": "0A0A1F0A1F0A0A",
    "*": "0004150E150400", "<": "02040810080402", ">": "08040201020408",
    "'": "04040800000000", '"': "0A0A0000000000", "^": "040A1100000000",
    "|": "04040404040404", "~": "00000815020000",
}


def _glyph_cell(hex_rows):
    """A (7, 6) boolean character cell: the 5-pixel glyph and a blank column."""
    rows = [int(hex_rows[2 * r:2 * r + 2], 16) for r in range(GLYPH_H)]
    return np.array([[(row >> (GLYPH_W - 1 - c)) & 1 for c in range(GLYPH_W)] + [0]
                     for row in rows], dtype=bool)


_GLYPH_CELLS = {ch: _glyph_cell(code) for ch, code in _FONT_HEX.items()}


def text_mask(text, scale):
    """Boolean (7 scale, 6 scale len(text)) image of ``text``, each font pixel a
    ``scale`` x ``scale`` block; unknown characters print as '?'."""
    if not text:
        return np.zeros((GLYPH_H * scale, 0), dtype=bool)
    line = np.hstack([_GLYPH_CELLS.get(ch, _GLYPH_CELLS["?"]) for ch in text])
    return line.repeat(scale, axis=0).repeat(scale, axis=1)


def stamp(image, mask, row, col, colour):
    """Paint ``colour`` where ``mask`` is set, top-left at (row, col), clipped to
    the image on every side."""
    if row < 0:
        mask, row = mask[-row:], 0
    if col < 0:
        mask, col = mask[:, -col:], 0
    h = max(0, min(mask.shape[0], image.shape[0] - row))
    w = max(0, min(mask.shape[1], image.shape[1] - col))
    if h and w:
        image[row:row + h, col:col + w][mask[:h, :w]] = colour


def format_time(t):
    t = float(t)
    return f"{t:.3f}" if t == 0.0 or 1e-2 <= abs(t) < 1e5 else f"{t:.3e}"


def even(n):
    return max(2, 2 * int(round(n / 2.0)))
