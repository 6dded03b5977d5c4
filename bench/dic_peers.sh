#!/usr/bin/env bash
# DIC peers in one run: cellinject and pyvale on the same exact-shift speckle images.
#
# Images: `cellinject dic synth` (sum of Gaussians integrated over each pixel, 2 grey
# levels of Gaussian noise, 8-bit), 512x512, shifts of 0.1, 0.25 and 0.5 px along x.
# Both tools run their full-field, reliability-guided mode with 33x33 subsets, affine
# shape functions, ZNSSD and B-spline interpolation, on the same grid (step STEP, 10
# unless given), with two threads. Printed per tool and shift: bias and standard deviation of u (px), and points
# per second of the correlation itself (timed inside each tool, image loading excluded).
#
# pyvale is installed from PyPI into target/peers-venv on the first run (large: vtk,
# PyQt6, opencv...). Usage: bash bench/dic_peers.sh [STEP]
set -euo pipefail
cd "$(dirname "$0")/.."
step="${1:-10}"
case "$step" in ''|*[!0-9]*|0) echo "dic_peers.sh: STEP must be a positive whole number of pixels, got '$step'" >&2; exit 2;; esac
work=target/dic-peers
venv=target/peers-venv
mkdir -p "$work"
cargo build --release --quiet
bin=target/release/cellinject
if [ ! -x "$venv/bin/python" ]; then
  python3 -m venv "$venv"
  "$venv/bin/pip" install --quiet --upgrade pip
  "$venv/bin/pip" install --quiet pyvale
fi

printf '%-10s %-7s %10s %10s %12s %10s\n' tool shift bias_px std_px points_per_s points
for s in 0.1 0.25 0.5; do
  ref="$work/ref_$s.png"; cur="$work/cur_$s.png"
  "$bin" dic synth --size 512,512 --shift "$s,0" --noise 2 --seed 7 --reference "$ref" --current "$cur" >/dev/null
  # cellinject
  out=$("$bin" dic field --reference "$ref" --current "$cur" --step "$step" --subset 33 --threads 2 --force --out "$work/ci_$s.csv")
  pps=$(printf '%s\n' "$out" | sed -n 's/.*(\([0-9.]*\) points\/s).*/\1/p' | head -1)
  python3 - "$work/ci_$s.csv" "$s" "$pps" <<'PY'
import csv, sys, statistics
rows = [r for r in csv.DictReader(open(sys.argv[1])) if r["u"] and r["converged"] == "true"]
u = [float(r["u"]) - float(sys.argv[2]) for r in rows]
print(f"{'cellinject':<10} {sys.argv[2]:<7} {statistics.mean(u):10.5f} {statistics.stdev(u):10.5f} {float(sys.argv[3]):12.0f} {len(u):10d}")
PY
  # pyvale
  "$venv/bin/python" - "$ref" "$cur" "$s" "$work" "$step" <<'PY'
import sys, time, glob, os
import numpy as np
import imageio.v3 as iio
from pyvale import dic
ref, cur, shift, work, step = sys.argv[1], sys.argv[2], float(sys.argv[3]), sys.argv[4], int(sys.argv[5])
r = iio.imread(ref).astype(np.float32)
c = iio.imread(cur).astype(np.float32)
mask = np.zeros(r.shape, dtype=bool)
mask[17:-17, 17:-17] = True
out = os.path.join(work, f"pv_{shift}_{step}")
os.makedirs(out, exist_ok=True)
t = time.perf_counter()
dic.calculate_2d(r, c, mask, [256, 256], subset_size=33, subset_step=step,
                 correlation_criteria="ZNSSD", shape_function="AFFINE",
                 interpolation_routine="BSPLINE", num_threads=2,
                 method="SINGLEWINDOW_RG", output_basepath=out, print_level=0)
dt = time.perf_counter() - t
files = sorted(glob.glob(os.path.join(out, "*.csv")))
import csv
rows = [r for r in csv.reader(open(files[-1])) if r]
hdr = [h for h in rows[0] if h]
iu, ic = hdr.index("disp_u"), hdr.index("converged")
u = np.array([float(r[iu]) for r in rows[1:] if float(r[ic]) == 1.0]) - shift
print(f"{'pyvale':<10} {shift:<7} {u.mean():10.5f} {u.std(ddof=1):10.5f} {len(u)/dt:12.0f} {len(u):10d}")
PY
done
