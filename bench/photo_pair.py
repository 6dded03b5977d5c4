#!/usr/bin/env python3
"""A 1024 x 1024 pair of real photographs with an exact sub-pixel shift, for timing `dic field`.

The six test photographs (crates/dic/tests/data/photos, 256 x 256) tiled 4 x 4 into a
1024 x 1024 mosaic, shifted by a band-limited (Fourier) shift of its mirror-symmetric
periodic extension, as tests/real_images.rs does, with 1.5 grey levels of Gaussian noise
and rounded to 8 bits; the reference gets the same noise and rounding unshifted.

Usage: python3 bench/photo_pair.py REF.png CUR.png [--shift U,V] [--seed N] [--force]
Needs numpy and imageio (target/peers-venv, made by bench/dic_peers.sh, has both).
"""
import argparse
import os
import sys

try:
    import numpy as np
    import imageio.v3 as iio
except ImportError as e:  # pragma: no cover
    print(f"photo_pair.py: needs numpy and imageio ({e}); target/peers-venv/bin/python has both", file=sys.stderr)
    sys.exit(2)

HERE = os.path.dirname(os.path.abspath(__file__))
PHOTOS = os.path.join(HERE, "..", "crates", "dic", "tests", "data", "photos")
NAMES = ["astronaut", "brick", "camera_field", "camera_sky_coat", "grass", "gravel"]


def mosaic() -> np.ndarray:
    tiles = [iio.imread(os.path.join(PHOTOS, n + ".png")).astype(float) for n in NAMES]
    rows = [np.hstack([tiles[(4 * j + i) % len(tiles)] for i in range(4)]) for j in range(4)]
    return np.vstack(rows)


def fourier_shift(img: np.ndarray, u: float, v: float) -> np.ndarray:
    """The image moved by (u, v): the value at (x, y) is the scene's at (x - u, y - v)."""
    h, w = img.shape
    ext = np.block([[img, img[:, ::-1]], [img[::-1, :], img[::-1, ::-1]]])
    f = np.fft.fft2(ext)
    ky = np.fft.fftfreq(2 * h)[:, None]
    kx = np.fft.fftfreq(2 * w)[None, :]
    f *= np.exp(-2j * np.pi * (kx * u + ky * v))
    return np.real(np.fft.ifft2(f))[:h, :w]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("reference")
    ap.add_argument("current")
    ap.add_argument("--shift", default="0.35,-0.2", help="u,v in pixels (default 0.35,-0.2)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--force", action="store_true", help="replace REF.png and CUR.png if they exist")
    a = ap.parse_args()
    try:
        u, v = (float(s) for s in a.shift.split(","))
    except ValueError:
        ap.error(f"--shift must be two numbers U,V, not '{a.shift}'")
    if not (np.isfinite(u) and np.isfinite(v)):
        ap.error(f"--shift must be finite, not '{a.shift}'")
    if os.path.abspath(a.reference) == os.path.abspath(a.current):
        ap.error("the reference and the current image must be two files")
    for path in (a.reference, a.current):
        if os.path.exists(path) and not a.force:
            ap.error(f"{path} exists; --force replaces it")
    rng = np.random.default_rng(a.seed)
    scene = mosaic()
    for path, img in ((a.reference, scene), (a.current, fourier_shift(scene, u, v))):
        noisy = img + rng.normal(0.0, 1.5, img.shape)
        iio.imwrite(path, np.clip(np.round(noisy), 0, 255).astype(np.uint8))
    print(f"wrote {a.reference} and {a.current} (1024 x 1024, shift {u}, {v} px)")


if __name__ == "__main__":
    main()
