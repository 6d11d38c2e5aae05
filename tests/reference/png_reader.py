"""A plain PNG decoder written from the PNG specification (ISO/IEC 15948), numpy and zlib only: Pillow reads 16-bit
RGB(A) files as 8-bit, so tests that check 16-bit samples read them here. Non-interlaced truecolour / grey (with or
without alpha), 8 or 16 bits."""

from __future__ import annotations

import struct
import zlib

import numpy as np

CHANNELS = {0: 1, 2: 3, 4: 2, 6: 4}  # colour type -> samples per pixel


def read_png(path) -> tuple[np.ndarray, int]:
    """(H, W, C) uint8 or uint16 samples and the bit depth."""
    data = open(path, "rb").read()
    assert data[:8] == b"\x89PNG\r\n\x1a\n", f"{path}: not a PNG"
    pos, idat, header = 8, b"", None
    while pos < len(data):
        length, kind = struct.unpack(">I4s", data[pos : pos + 8])
        body = data[pos + 8 : pos + 8 + length]
        if kind == b"IHDR":
            header = struct.unpack(">IIBBBBB", body)
        elif kind == b"IDAT":
            idat += body
        pos += 12 + length
    width, height, bits, colour, _, _, interlace = header
    assert interlace == 0 and colour in CHANNELS and bits in (8, 16)
    bpp = CHANNELS[colour] * bits // 8
    stride = width * bpp
    raw = zlib.decompress(idat)
    out = np.zeros((height, stride), dtype=np.int64)
    prev = np.zeros(stride, dtype=np.int64)
    for r in range(height):
        line = raw[r * (stride + 1) : (r + 1) * (stride + 1)]
        kind, cur = line[0], np.frombuffer(line[1:], dtype=np.uint8).astype(np.int64)
        rec = np.zeros(stride, dtype=np.int64)
        for i in range(stride):
            a = rec[i - bpp] if i >= bpp else 0
            c = prev[i - bpp] if i >= bpp else 0
            b = prev[i]
            if kind == 0:
                pred = 0
            elif kind == 1:
                pred = a
            elif kind == 2:
                pred = b
            elif kind == 3:
                pred = (a + b) // 2
            else:
                p = a + b - c
                pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
                pred = a if pa <= pb and pa <= pc else b if pb <= pc else c
            rec[i] = (cur[i] + pred) & 0xFF
        out[r], prev = rec, rec
    samples = out.astype(np.uint8).reshape(height, width, -1)
    if bits == 16:
        samples = (samples[..., 0::2].astype(np.uint16) << 8) | samples[..., 1::2]
    return samples, bits
