#!/usr/bin/env bash
# The longest run the twin can hold (issue 20): the largest plate the microscope sees
# whole at the run's zoom (2.5x: 10 rows x 15 columns of 150 um wells, 205 um of the
# pipette in view above the top row, where 200 are needed, and 5 um to spare below the
# bottom row), generated from each seed, injected with the
# prototype's description (temperature drift on: 1 K/h). For each seed it prints
# whether the run completed, its mean and largest tip error at injection (the twin's
# truth), the mean of each tenth of the run's injections in order (drift would show as
# a trend) and the re-checks the workflow made with their verdicts.
#
# Usage: bash bench/long_run.sh [--seeds FIRST-LAST] [--config FILE] [--jobs J]
# e.g.   bash bench/long_run.sh --seeds 1-10
set -euo pipefail
cd "$(dirname "$0")/.."
seeds=1-5
config=
jobs=2
while [ $# -gt 0 ]; do
  case $1 in
    --seeds) seeds=$2; shift 2 ;;
    --config) config=$2; shift 2 ;;
    --jobs) jobs=$2; shift 2 ;;
    -h|--help) sed -n '2,13p' "$0"; exit 0 ;;
    *) echo "long_run.sh: unknown argument '$1' (see --help)" >&2; exit 2 ;;
  esac
done
case $seeds in
  *-*) first=${seeds%-*}; last=${seeds#*-} ;;
  *) echo "long_run.sh: --seeds takes FIRST-LAST, got '$seeds'" >&2; exit 2 ;;
esac
if [ -n "$config" ] && [ ! -f "$config" ]; then
  echo "long_run.sh: --config $config: no such file" >&2; exit 2
fi
cargo build --release --quiet --locked
bin=${CARGO_TARGET_DIR:-$PWD/target}/release/cellinject
work=$PWD/target/long-run
rm -rf "$work"
mkdir -p "$work"
export bin work config

one() {
  local s=$1 d="$work/s$1" rc=0
  mkdir -p "$d"
  "$bin" plate generate --rows 10 --cols 15 --origin=-1.05e-3,-0.540e-3 --seed "$s" \
    --out "$d/plate.toml" >/dev/null
  "$bin" run ${config:+--config "$config"} --plate "$d/plate.toml" --seed "$s" \
    --db "$d/runs.sqlite" --format json >"$d/run.json" 2>"$d/run.err" || rc=$?
  echo "$s $rc"
}
export -f one

t0=$SECONDS
seq "$first" "$last" | xargs -P "$jobs" -L 1 bash -c 'one $0' > "$work/exit.txt"
echo "wall time: $((SECONDS - t0)) s for $(wc -l < "$work/exit.txt") runs, $jobs at a time"
python3 - "$work" <<'EOF'
import json, os, statistics, sys
work = sys.argv[1]
codes = dict(l.split() for l in open(os.path.join(work, "exit.txt")))
means, worst_tenths = [], []
for s in sorted(codes, key=int):
    path = os.path.join(work, f"s{s}", "run.json")
    try:
        r = json.load(open(path))
    except (OSError, ValueError):
        err = open(os.path.join(work, f"s{s}", "run.err")).read().strip().splitlines()
        print(f"seed {s}: exit {codes[s]}: {err[-1] if err else 'no output'}")
        continue
    e = [a["tip_error_m"] * 1e6 for a in r["attempts"]
         if a["outcome"] == "injected" and a["tip_error_m"] is not None]
    n = len(e)
    tenths = [statistics.mean(e[k * n // 10:(k + 1) * n // 10]) for k in range(10)] if n >= 10 else [statistics.mean(e)]
    checks = [x for x in r["events"] if x["event"] == "rechecked"]
    remapped = sum("mapped to the stage again" in x["reason"] for x in checks)
    means.append(statistics.mean(e))
    worst_tenths.append(max(tenths))
    print(f"seed {s}: exit {codes[s]}, {r['cells_found']} cells, {r['injected']} injected, "
          f"{r['sim_time_s']:.0f} s; tip error mean {statistics.mean(e):.3f} um, max {max(e):.2f} um; "
          f"tenths {' '.join(f'{t:.2f}' for t in tenths)}; re-checks {len(checks)} ({remapped} mapped again)"
          + (f"; stopped: {r['stopped']}" if r["stopped"] else ""))
if means:
    print(f"{len(means)} runs: mean tip error median {statistics.median(means):.3f} um, worst {max(means):.3f} um; "
          f"worst tenth median {statistics.median(worst_tenths):.3f} um, worst {max(worst_tenths):.3f} um; "
          f"exits other than 0: {sum(c != '0' for c in codes.values())}")
EOF
