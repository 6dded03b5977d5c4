"""Shared fixtures: the `cellinject` CLI to compare with, a private joint cache, and
PNG reading and writing in plain Python (the package needs no imaging library)."""

import json
import os
import shutil
import struct
import subprocess
import zlib
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
PHOTOS = ROOT / "crates" / "dic" / "tests" / "data" / "photos"


def pytest_configure(config):
    # The FEA's joint cache of the tests, shared by the CLI and Python (both read
    # XDG_CACHE_HOME), never the user's.
    cache = ROOT / "target" / "pytest-cache"
    cache.mkdir(parents=True, exist_ok=True)
    os.environ["XDG_CACHE_HOME"] = str(cache)


@pytest.fixture(scope="session")
def cli():
    """Runs the `cellinject` binary (CELLINJECT_BIN, else the one on PATH) and returns
    its parsed JSON output."""
    exe = os.environ.get("CELLINJECT_BIN") or shutil.which("cellinject")
    if not exe:
        if os.environ.get("CELLINJECT_PYTEST") == "required":
            pytest.fail("CELLINJECT_BIN is not set and no cellinject on PATH")
        pytest.skip("no cellinject binary (set CELLINJECT_BIN) to compare with")

    def run(*args, cwd=None, code=0):
        o = subprocess.run([exe, *map(str, args)], capture_output=True, cwd=cwd, text=True)
        assert o.returncode == code, o.stderr
        return json.loads(o.stdout) if o.stdout.strip() else None

    return run


def read_png(path):
    """An 8-bit grey, non-interlaced PNG as a uint8 array (rows, columns)."""
    data = Path(path).read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    pos, idat, w, h = 8, b"", 0, 0
    while pos < len(data):
        n, kind = struct.unpack(">I4s", data[pos : pos + 8])
        body = data[pos + 8 : pos + 8 + n]
        if kind == b"IHDR":
            w, h, depth, colour, _, _, interlace = struct.unpack(">IIBBBBB", body)
            assert (depth, colour, interlace) == (8, 0, 0), "8-bit grey only"
        elif kind == b"IDAT":
            idat += body
        pos += 12 + n
    raw = zlib.decompress(idat)
    out = np.zeros((h, w), np.uint8)
    prev = np.zeros(w, np.int32)
    for y in range(h):
        f, line = raw[y * (w + 1)], np.frombuffer(raw, np.uint8, w, y * (w + 1) + 1).astype(np.int32)
        cur = np.zeros(w, np.int32)
        for x in range(w):
            a = cur[x - 1] if x else 0
            b = prev[x]
            c = prev[x - 1] if x else 0
            if f == 0:
                p = 0
            elif f == 1:
                p = a
            elif f == 2:
                p = b
            elif f == 3:
                p = (a + b) // 2
            else:
                pa, pb, pc = abs(b - c), abs(a - c), abs(a + b - 2 * c)
                p = a if pa <= pb and pa <= pc else (b if pb <= pc else c)
            cur[x] = (line[x] + p) & 0xFF
        out[y] = cur
        prev = cur
    return out


def write_png(path, img):
    """A uint8 array (rows, columns) as an 8-bit grey PNG."""
    img = np.asarray(img, np.uint8)
    h, w = img.shape
    raw = b"".join(b"\x00" + img[y].tobytes() for y in range(h))

    def chunk(kind, body):
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))

    Path(path).write_bytes(
        b"\x89PNG\r\n\x1a\n"
        + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 0, 0, 0, 0))
        + chunk(b"IDAT", zlib.compress(raw))
        + chunk(b"IEND", b"")
    )


def fourier_shift(img, u, v):
    """The band-limited shift of the image's mirror-symmetric periodic extension: the
    result at (x, y) is its trigonometric interpolant at (x - u, y - v). Independent of
    the DIC and of its spline."""
    h, w = img.shape
    e = np.block([[img, img[:, ::-1]], [img[::-1, :], img[::-1, ::-1]]]).astype(float)
    fy = np.fft.fftfreq(2 * h)[:, None]
    fx = np.fft.fftfreq(2 * w)[None, :]
    s = np.fft.ifft2(np.fft.fft2(e) * np.exp(-2j * np.pi * (fx * u + fy * v))).real
    return s[:h, :w]
