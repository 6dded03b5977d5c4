#!/usr/bin/env bash
# Seed sweep (issue 20): does every figure of the control work hold on every day of the
# bench? On the twin, a seed is another day: other sensor and amplifier noise, another
# marker texture, other joint slips. For each approach and seed this runs, on the
# release build:
#   1. `cellinject calibrate all` (pixels, hysteresis, Jacobian): exit code and reason;
#   2. with --repeat N (default 0: skipped), `experiment repeatability --control closed
#      --runs N` on that seed's calibration: the true max error, camera vs truth and
#      the runs that never settled;
#   3. with --run, `cellinject run` on that seed's default plate (approach 2 only: the
#      twin's own): its exit code, the mean tip error of its injections (twin's truth)
#      and the worst mean of a tenth of the run (in order: drift would show as a trend).
# Then it prints, per approach, the failure count and every failure's reason, and the
# median and worst of each figure. Results go to target/seed-sweep/results.tsv (or
# $SWEEP_DIR/results.tsv: two sweeps at once need two directories). With $SWEEP_BIN set to
# a cellinject binary, nothing is built and that binary runs (a sweep of an hour keeps
# one version while the workspace is rebuilt).
#
# Usage: bash bench/seed_sweep.sh [--seeds FIRST-LAST] [--approaches "1 2"] [--repeat N] [--run] [--jobs J]
# e.g.   bash bench/seed_sweep.sh --seeds 1-200                 # the calibration sweep
#        bash bench/seed_sweep.sh --seeds 1-20 --repeat 200     # with closed-loop repeatability
#        bash bench/seed_sweep.sh --seeds 1-20 --approaches 2 --run   # with an injection run
set -euo pipefail
cd "$(dirname "$0")/.."
seeds=1-20
approaches="1 2"
repeat=0
run=0
jobs=2
while [ $# -gt 0 ]; do
  case $1 in
    --seeds) seeds=$2; shift 2 ;;
    --approaches) approaches=$2; shift 2 ;;
    --repeat) repeat=$2; shift 2 ;;
    --run) run=1; shift ;;
    --jobs) jobs=$2; shift 2 ;;
    -h|--help) sed -n '2,23p' "$0"; exit 0 ;;
    *) echo "seed_sweep.sh: unknown argument '$1' (see --help)" >&2; exit 2 ;;
  esac
done
case $seeds in
  *-*) first=${seeds%-*}; last=${seeds#*-} ;;
  *) echo "seed_sweep.sh: --seeds takes FIRST-LAST, got '$seeds'" >&2; exit 2 ;;
esac
if [ -n "${SWEEP_BIN:-}" ]; then
  bin=$SWEEP_BIN
  [ -x "$bin" ] || { echo "seed_sweep.sh: SWEEP_BIN='$bin' is not an executable file" >&2; exit 2; }
else
  cargo build --release --quiet --locked
  bin=${CARGO_TARGET_DIR:-$PWD/target}/release/cellinject
fi
work=${SWEEP_DIR:-$PWD/target/seed-sweep}
rm -rf "$work"
mkdir -p "$work"
export bin work repeat run

one() {
  local a=$1 s=$2 d="$work/a$1-s$2" line
  mkdir -p "$d"
  if "$bin" calibrate all --approach "$a" --seed "$s" --out "$d/cal" >/dev/null 2>"$d/cal.err"; then
    line="$a	$s	ok	"
  else
    line="$a	$s	fail	$(tail -1 "$d/cal.err" | tr '\t' ' ')"
  fi
  if [ "$repeat" -gt 0 ] && [ -d "$d/cal" ]; then
    if "$bin" experiment repeatability --approach "$a" --seed "$s" --control closed \
        --runs "$repeat" --calibration "$d/cal" --out "$d/rep" --format json \
        >"$d/rep.json" 2>"$d/rep.err"; then
      line="$line	$(python3 -c '
import json, sys
d = json.load(open(sys.argv[1]))
t = d["true_max_error_m"]
c = d["camera_vs_truth_m"]
print("%.1f\t%.1f\t%d" % (max(t) * 1e9, c * 1e9, d["unsettled_runs"]))
' "$d/rep.json")"
    else
      line="$line	fail: $(tail -1 "$d/rep.err" | tr '\t' ' ')		"
    fi
  fi
  if [ "$run" -eq 1 ] && [ "$a" = 2 ]; then
    local rc=0
    "$bin" run --seed "$s" --db "$d/runs.sqlite" --format json >"$d/run.json" 2>"$d/run.err" || rc=$?
    "$bin" runs export --db "$d/runs.sqlite" --format csv >"$d/attempts.csv" 2>/dev/null || true
    line="$line	run:$rc:$(python3 -c '
import csv, sys
e = [float(r["tip_error_m"]) for r in csv.DictReader(open(sys.argv[1]))
     if r["tip_error_m"] and r["outcome"] == "injected"]
n = len(e)
# The mean of each tenth of the run (injections in order): drift shows as a trend.
tenths = [e[k * n // 10:(k + 1) * n // 10] for k in range(10)] if n >= 10 else [e]
worst = max(sum(t) / len(t) for t in tenths if t) if e else 0.0
print(f"{sum(e) / n * 1e6:.3f}:{worst * 1e6:.3f}" if e else ":")
' "$d/attempts.csv"):$(tail -1 "$d/run.err" | tr '\t:' '  ')"
  fi
  echo "$line"
}
export -f one

t0=$SECONDS
for a in $approaches; do
  for s in $(seq "$first" "$last"); do echo "$a $s"; done
done | xargs -P "$jobs" -L 1 bash -c 'one $0 $1' > "$work/results.tsv"
echo "wall time: $((SECONDS - t0)) s for $(wc -l < "$work/results.tsv") runs, $jobs at a time"
python3 - "$work/results.tsv" "$repeat" <<'EOF'
import statistics, sys
rows = [l.rstrip("\n").split("\t") for l in open(sys.argv[1]) if l.strip()]
repeat = int(sys.argv[2])
for a in sorted({r[0] for r in rows}):
    rs = sorted((r for r in rows if r[0] == a), key=lambda r: int(r[1]))
    fails = [r for r in rs if r[2] != "ok"]
    print(f"approach {a}: calibrate all failed on {len(fails)} of {len(rs)} seeds")
    for r in fails:
        print(f"  seed {r[1]}: {r[3]}")
    if repeat:
        ok = [r for r in rs if len(r) > 5 and r[4] and not r[4].startswith("fail")]
        bad = [r for r in rs if len(r) > 4 and r[4].startswith("fail")]
        for r in bad:
            print(f"  repeatability failed, seed {r[1]}: {r[4]}")
        if ok:
            err = [float(r[4]) for r in ok]
            cam = [float(r[5]) for r in ok]
            uns = [int(r[6]) for r in ok]
            w = max(ok, key=lambda r: float(r[4]))
            print(f"  closed-loop repeatability ({repeat} runs) on {len(ok)} seeds: true max error "
                  f"median {statistics.median(err):.1f} nm, worst {max(err):.1f} nm (seed {w[1]}); "
                  f"cameras vs truth median {statistics.median(cam):.1f} nm, worst {max(cam):.1f} nm; "
                  f"runs never settled: {sum(uns)}")
    runs = [next((c for c in r if c.startswith("run:")), None) for r in rs]
    runs = [(r[1], x.split(":", 4)) for r, x in zip(rs, runs) if x]
    if runs:
        bad = [(s, x) for s, x in runs if x[1] != "0"]
        tips = [(float(x[2]), float(x[3]), s) for s, x in runs if x[2]]
        line = f"  run: {len(runs) - len(bad)} of {len(runs)} completed"
        if tips:
            m = max(tips)
            t = max(tips, key=lambda v: v[1])
            line += (f"; mean tip error median {statistics.median(v[0] for v in tips):.3f} um, "
                     f"worst {m[0]:.3f} um (seed {m[2]}); worst tenth of a run {t[1]:.3f} um (seed {t[2]})")
        print(line)
        for s, x in bad:
            print(f"    seed {s}: the run stopped: {x[4]}")
EOF
