#!/usr/bin/env bash
# Two builds of cellinject side by side on the bench/dic_peers.sh speckle pairs: a change
# to the correlation measured before and after in one sitting.
#
# Runs `dic field --step STEP --subset 33 --threads 2` with BASE and NEW in turn (BASE,
# NEW, BASE, NEW ...), ROUNDS times on each of the three pairs (shifts 0.1, 0.25 and 0.5
# px), and prints the median, least and largest points per second of each (the figure
# of the summary line: the correlation alone, image loading excluded) and the ratio of
# the medians. Alternating keeps the ratio meaningful when the machine's speed drifts
# (by 20-30 % from hour to hour here); compare ratios, not figures of different runs.
#
# Usage: bash bench/dic_pair.sh BASE NEW [STEP] [ROUNDS]
#   BASE, NEW  cellinject binaries, e.g. a copy of target/release/cellinject built at the
#              commit before the change, and target/release/cellinject
#   STEP       grid step in pixels (10 unless given); ROUNDS 5 unless given
# The pairs are made (as bench/dic_peers.sh makes them) in target/dic-peers when missing.
set -euo pipefail
cd "$(dirname "$0")/.."
usage() { echo "usage: bash bench/dic_pair.sh BASE NEW [STEP] [ROUNDS]" >&2; exit 2; }
[ $# -ge 2 ] && [ $# -le 4 ] || usage
base=$1; new=$2; step="${3:-10}"; rounds="${4:-5}"
for b in "$base" "$new"; do
  [ -x "$b" ] || { echo "dic_pair.sh: '$b' is not an executable cellinject binary" >&2; exit 2; }
done
case "$step" in ''|*[!0-9]*|0) echo "dic_pair.sh: STEP must be a positive whole number of pixels, got '$step'" >&2; exit 2;; esac
case "$rounds" in ''|*[!0-9]*|0) echo "dic_pair.sh: ROUNDS must be a positive whole number, got '$rounds'" >&2; exit 2;; esac
work=target/dic-peers
mkdir -p "$work"
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
for s in 0.1 0.25 0.5; do
  if [ ! -f "$work/ref_$s.png" ] || [ ! -f "$work/cur_$s.png" ]; then
    "$new" dic synth --size 512,512 --shift "$s,0" --noise 2 --seed 7 \
      --reference "$work/ref_$s.png" --current "$work/cur_$s.png" >/dev/null
  fi
done
for _ in $(seq "$rounds"); do
  for s in 0.1 0.25 0.5; do
    for side in base new; do
      bin=$base; [ "$side" = new ] && bin=$new
      summary=$("$bin" dic field --reference "$work/ref_$s.png" --current "$work/cur_$s.png" \
        --step "$step" --subset 33 --threads 2 --force --out "$out/$side.csv")
      pps=$(printf '%s\n' "$summary" | sed -n 's/.*(\([0-9.]*\) points\/s).*/\1/p' | head -1)
      [ -n "$pps" ] || { echo "dic_pair.sh: no points/s in $bin's summary: $summary" >&2; exit 1; }
      echo "$side $pps"
    done
  done
done | python3 -c '
import statistics as st, sys
d = {}
for line in sys.stdin:
    side, v = line.split()
    d.setdefault(side, []).append(float(v))
for side in ("base", "new"):
    v = d[side]
    print(f"{side:<5} median {st.median(v):8.0f}  least {min(v):8.0f}  largest {max(v):8.0f}  points/s ({len(v)} runs)")
ratio = st.median(d["new"]) / st.median(d["base"])
print(f"new/base {ratio:.3f} (medians)")
'
