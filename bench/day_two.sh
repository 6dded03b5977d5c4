#!/usr/bin/env bash
# Day two on the bench (issue 36): the figures of a run from saved calibrations, of a
# dashboard session's later runs, and of hand-written strip plates, by command. Each
# mode runs the release binary on the twin over several seeds and ends with the median
# and the worst case.
#
#   session      several runs of one `cellinject serve --fast` session per seed, each
#                started with `POST /api/run` once the previous has finished: cells
#                injected of found, mean tip error at injection (the twin's truth) and
#                each later run's difference from the session's first
#                (default seeds "1 2 3 4 5", --runs 3)
#   calibration  `calibrate all`, then `run` fresh and `run --calibration` on the same
#                seed: both runs' cells and mean tip errors and their difference
#                (default seeds "1 2 3 4 5 6")
#   strip        `python3 bench/strip_plate.py SEED` (3 x 40 wells, pitch 200 um, 117
#                cells, touching doublets with a 10 um partner), `run --plate` on the
#                twin of seed SEED + --offset (default 0), scored against the plate:
#                failed, skipped, the 10 um partners' worst diameter error, cells/min
#                (default seeds "11 12 13 14 15 16")
#
# Usage: bash bench/day_two.sh MODE [--seeds "1 2 3"] [--runs N] [--offset K] [--bin PATH]
# (the release binary target/release/cellinject by default, built if missing)
set -euo pipefail
cd "$(dirname "$0")/.."
usage() { sed -n 2,22p "$0"; }
mode=${1:-}
case "$mode" in
  session) seeds="1 2 3 4 5" ;;
  calibration) seeds="1 2 3 4 5 6" ;;
  strip) seeds="11 12 13 14 15 16" ;;
  -h|--help) usage; exit 0 ;;
  *) echo "day_two.sh: the mode must be session, calibration or strip, not '$mode' (see --help)" >&2; exit 2 ;;
esac
shift
runs=3
offset=0
bin=target/release/cellinject
while [ $# -gt 0 ]; do
  case "$1" in
    --seeds) seeds=$2; shift 2 ;;
    --runs) runs=$2; shift 2 ;;
    --offset) offset=$2; shift 2 ;;
    --bin) bin=$2; shift 2 ;;
    -h|--help) usage; exit 0 ;;
    *) echo "day_two.sh: unknown argument $1 (see --help)" >&2; exit 2 ;;
  esac
done
for n in $seeds "$runs" "$offset"; do
  case "$n" in ''|*[!0-9]*) echo "day_two.sh: '$n' is not a whole number (--seeds, --runs, --offset)" >&2; exit 2 ;; esac
done
[ -x "$bin" ] || cargo build --release -q -p cellinject
dir=$(mktemp -d)
pid=""
trap '[ -n "$pid" ] && kill "$pid" 2>/dev/null; rm -rf "$dir"' EXIT

# "injected/found mean_tip_um" of run $2 (default the latest) in database $1.
summary() {
  "$bin" runs show --db "$1" ${2:+--run "$2"} | python3 -c '
import json, sys
a = json.load(sys.stdin)["attempts"]
ok = [x for x in a if x.get("outcome") == "injected"]
e = [x["tip_error_m"] for x in ok if x.get("tip_error_m") is not None]
print(f"{len(ok)}/{len(a)} {1e6 * sum(e) / max(len(e), 1):.3f}")'
}

# The median and worst of the numbers on standard input, labelled $1.
spread() {
  python3 -c '
import statistics, sys
d = [float(x) for x in sys.stdin.read().split()]
if not d:
    sys.exit("no figures")
print(f"{sys.argv[1]}: mean {statistics.mean(d):+.3f}, median {statistics.median(d):+.3f}, worst {max(d):+.3f} ({len(d)})")' "$1"
}

status_of() {
  "$bin" runs show --db "$1" --run "$2" 2>/dev/null \
    | python3 -c 'import json,sys; print(json.load(sys.stdin)["run"]["status"])' 2>/dev/null || true
}

session() {
  printf 'seed\trun\tinjected/found\tmean_tip_um\tdelta_um\n'
  : >"$dir/deltas"
  for seed in $seeds; do
    "$bin" serve --fast --seed "$seed" --db "$dir/s$seed.sqlite" --bind 127.0.0.1:0 >"$dir/out$seed" 2>&1 &
    pid=$!
    url=""
    for _ in $(seq 1 300); do
      url=$(grep -oE 'http://127\.0\.0\.1:[0-9]+' "$dir/out$seed" | head -1 || true)
      [ -n "$url" ] && break
      sleep 0.2
    done
    [ -n "$url" ] || { echo "seed $seed: the dashboard did not say its address" >&2; cat "$dir/out$seed" >&2; exit 1; }
    first=""
    for k in $(seq 1 "$runs"); do
      curl -sf -X POST "$url/api/run" >/dev/null
      for _ in $(seq 1 2400); do
        case "$(status_of "$dir/s$seed.sqlite" "$k")" in finished|stopped|aborted|failed) break ;; esac
        sleep 0.5
      done
      read -r got mean < <(summary "$dir/s$seed.sqlite" "$k")
      if [ -z "$first" ]; then first=$mean; d="-"; else
        d=$(python3 -c "print(f'{$mean - $first:+.3f}')"); echo "$d" >>"$dir/deltas"; fi
      printf '%s\t%s\t%s\t%s\t%s\n' "$seed" "$k" "$got" "$mean" "$d"
    done
    kill "$pid" 2>/dev/null || true
    wait "$pid" 2>/dev/null || true
    pid=""
  done
  spread "later runs less the session's first, um" <"$dir/deltas"
}

calibration() {
  printf 'seed\tfresh\tfresh_um\tfile\tfile_um\tdelta_um\n'
  : >"$dir/deltas"
  for seed in $seeds; do
    "$bin" calibrate all --seed "$seed" --out "$dir/cal$seed" >/dev/null 2>&1
    "$bin" run --seed "$seed" --db "$dir/fresh$seed.sqlite" >/dev/null 2>&1 || true
    "$bin" run --seed "$seed" --calibration "$dir/cal$seed/hysteresis.json" \
      --db "$dir/file$seed.sqlite" >/dev/null 2>&1 || true
    read -r fc fm < <(summary "$dir/fresh$seed.sqlite")
    read -r lc lm < <(summary "$dir/file$seed.sqlite")
    d=$(python3 -c "print(f'{$lm - $fm:+.3f}')")
    echo "$d" >>"$dir/deltas"
    printf '%s\t%s\t%s\t%s\t%s\t%s\n' "$seed" "$fc" "$fm" "$lc" "$lm" "$d"
  done
  spread "the file's run less the fresh one, um" <"$dir/deltas"
}

strip() {
  printf 'plate\ttwin\tcells\tfailed\tskipped\tworst_partner_um\tmedian_um\tcells_per_min\n'
  : >"$dir/rows"
  for seed in $seeds; do
    twin=$((seed + offset))
    python3 bench/strip_plate.py "$seed" >"$dir/p$seed.toml"
    "$bin" run --plate "$dir/p$seed.toml" --seed "$twin" --db "$dir/r$seed.sqlite" >"$dir/out$seed" 2>&1 || true
    if ! "$bin" runs show --db "$dir/r$seed.sqlite" >"$dir/r$seed.json" 2>/dev/null; then
      echo "plate $seed: the run did not start: $(tail -1 "$dir/out$seed")" >&2
      continue
    fi
    s=$(python3 bench/strip_plate.py --score "$dir/p$seed.toml" "$dir/r$seed.json" | tail -1)
    cpm=$(grep -oE '[0-9.]+ cells per minute' "$dir/out$seed" | cut -d' ' -f1 || true)
    read -r _ n _ f _ k _ _ _ w _ m <<<"$s"
    printf '%s\t%s\t%s\t%s\t%s\t%s\t%s\t%s\n' "$seed" "$twin" "$n" "$f" "$k" "$w" "$m" "${cpm:-nan}"
    echo "$n $f $k $w ${cpm:-nan}" >>"$dir/rows"
  done
  python3 -c '
import statistics, sys
r = [x.split() for x in open(sys.argv[1]) if x.strip()]
if not r:
    sys.exit("no run finished")
fail = [(int(a[1]) + int(a[2])) / int(a[0]) for a in r]
c = [float(a[4]) for a in r]
print(f"failed or skipped: worst {100 * max(fail):.2f} %, median {100 * statistics.median(fail):.2f} %; "
      f"worst 10 um partner error {max(float(a[3]) for a in r):.2f} um; "
      f"cells/min: worst {min(c):.1f}, median {statistics.median(c):.1f}")' "$dir/rows"
}

"$mode"
