#!/usr/bin/env bash
# The figures and screenshots of docs/dashboard.md, from a run of today's build, so that
# the page stays current.
#
# Runs the default plate on the twin (seed 1) three ways: `cellinject run`, `cellinject
# serve --fast` and `cellinject serve` (paced: device time at wall time, some 5 min),
# the dashboard's runs started with `POST /api/run` and followed through
# `GET /api/status`; prints the "Measured" table, and with --write puts it in
# docs/dashboard.md between its `figures:begin` and `figures:end` comments. With
# --shots the page is photographed in headless Chromium (crates/cellinject/tests/e2e,
# `npm ci` there first) during a paced run and after its abort: docs/dashboard-run.png
# and docs/dashboard-aborted.png.
#
# Usage: bash docs/dashboard_figures.sh [--write] [--shots] [--no-paced]
set -euo pipefail
cd "$(dirname "$0")/.."
write=0; shots=0; paced=1
for a in "$@"; do
  case "$a" in
    --write) write=1 ;;
    --shots) shots=1 ;;
    --no-paced) paced=0 ;;
    -h|--help) sed -n '2,14p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
    *) echo "dashboard_figures.sh: unknown argument '$a' (--write, --shots, --no-paced)" >&2; exit 2 ;;
  esac
done
cargo build --release --quiet -p cellinject
bin=$PWD/target/release/cellinject
work=$(mktemp -d)
# The servers' process ids, one file each (`serve` runs in a command substitution's
# subshell, whose variables do not come back).
cleanup() {
  for f in "$work"/*.pid; do [ -e "$f" ] && kill "$(cat "$f")" 2>/dev/null || true; done
  rm -rf "$work"
}
trap cleanup EXIT

# `cellinject run`: its JSON summary and its wall time.
t0=$(date +%s.%N)
"$bin" run --seed 1 --db "$work/cli.sqlite" --format json > "$work/cli.json"
t1=$(date +%s.%N)
python3 - "$work/cli.json" "$t0" "$t1" > "$work/cli.row" <<'PY'
import json, sys
d = json.load(open(sys.argv[1]))
wall = float(sys.argv[3]) - float(sys.argv[2])
print(json.dumps({k: d[k] for k in ("cells_found", "injected", "skipped", "sim_time_s", "cells_per_min")} | {"wall_s": wall}))
PY

# A server on a free port; its address from its first line.
serve() {
  local log=$1; shift
  "$bin" serve --bind 127.0.0.1:0 --seed 1 --db "$work/$log.sqlite" "$@" 2> "$work/$log.err" > /dev/null &
  echo $! > "$work/$log.pid"
  local url=""
  for _ in $(seq 200); do
    url=$(sed -n 's/^dashboard: \(http:\/\/[^ ]*\).*/\1/p' "$work/$log.err" | head -1)
    [ -n "$url" ] && break
    sleep 0.1
  done
  [ -n "$url" ] || { echo "dashboard_figures.sh: the server did not start: $(cat "$work/$log.err")" >&2; exit 1; }
  echo "$url"
}

# A dashboard run from POST /api/run to the state `finished`, polled.
dashboard_run() {
  python3 - "$1" <<'PY'
import json, sys, time, urllib.request
url = sys.argv[1].rstrip("/")
def call(path, method="GET"):
    req = urllib.request.Request(url + path, method=method)
    with urllib.request.urlopen(req, timeout=30) as r:
        return json.load(r)
t0 = time.monotonic()
call("/api/run", "POST")
while True:
    st = call("/api/status")
    if st["state"] in ("finished", "aborted", "fault"):
        break
    if time.monotonic() - t0 > 1800:
        sys.exit("dashboard_figures.sh: the dashboard's run did not end within 30 min")
    time.sleep(0.5)
wall = time.monotonic() - t0
if st["state"] != "finished":
    sys.exit(f"dashboard_figures.sh: the dashboard's run ended {st['state']}: {st.get('message')}")
r = st["run"]
runs = call("/api/runs")
print(json.dumps({"cells_found": r["cells_found"], "injected": r["injected"], "skipped": r["skipped"],
                  "sim_time_s": runs[0]["sim_time_s"], "cells_per_min": r["cells_per_min"], "wall_s": wall}))
PY
}

fast=$(serve fast --fast)
dashboard_run "$fast" > "$work/fast.row"
if [ "$paced" = 1 ]; then
  url=$(serve paced)
  dashboard_run "$url" > "$work/paced.row"
fi

python3 - "$work" "$paced" > "$work/table.md" <<'PY'
import json, os, sys
work, paced = sys.argv[1], sys.argv[2] == "1"
cols = [("`cellinject run`", "cli"), ("`cellinject serve --fast`", "fast")]
if paced:
    cols.append(("`cellinject serve` (paced)", "paced"))
rows = {k: json.load(open(os.path.join(work, k + ".row"))) for _, k in cols}
line = lambda cells: "| " + " | ".join(cells) + " |"
out = [line([""] + [c for c, _ in cols]), line(["---"] * (len(cols) + 1))]
out.append(line(["cells found / injected / skipped"] + [f"{r['cells_found']} / {r['injected']} / {r['skipped']}" for r in (rows[k] for _, k in cols)]))
out.append(line(["device time of the run"] + [f"{rows[k]['sim_time_s']:.2f} s" for _, k in cols]))
out.append(line(["throughput (device time)"] + [f"{rows[k]['cells_per_min']:.3f} cells/min" for _, k in cols]))
out.append(line(["wall time"] + [f"{rows[k]['wall_s']:.1f} s" for _, k in cols]))
print("\n".join(out))
PY
cat "$work/table.md"

if [ "$write" = 1 ]; then
  python3 - docs/dashboard.md "$work/table.md" "$(git rev-parse --short HEAD 2>/dev/null || echo unknown)" <<'PY'
import sys, datetime
doc, table, rev = sys.argv[1], open(sys.argv[2]).read().strip(), sys.argv[3]
text = open(doc).read()
begin, end = "<!-- figures:begin -->", "<!-- figures:end -->"
if begin not in text or end not in text:
    sys.exit(f"dashboard_figures.sh: {doc} has no {begin} ... {end} block to replace")
head, rest = text.split(begin, 1)
_, tail = rest.split(end, 1)
when = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d")
new = f"{begin}\n(`bash docs/dashboard_figures.sh --write`, build {rev}, {when})\n\n{table}\n{end}"
tmp = doc + ".tmp"
open(tmp, "w").write(head + new + tail)
import os; os.replace(tmp, doc)
print(f"wrote the table into {doc}", file=sys.stderr)
PY
fi

if [ "$shots" = 1 ]; then
  e2e=crates/cellinject/tests/e2e
  [ -d "$e2e/node_modules/playwright-core" ] || { echo "dashboard_figures.sh: --shots needs playwright-core: (cd $e2e && npm ci)" >&2; exit 2; }
  url=$(serve shots)
  node "$e2e/dashboard.mjs" "$url" "$work" 12 > /dev/null
  cp "$work/dashboard-run.png" "$work/dashboard-aborted.png" docs/
  echo "wrote docs/dashboard-run.png and docs/dashboard-aborted.png" >&2
fi
