#!/usr/bin/env bash
# PI's own Python client (pipython) against `cellinject emulate gcs` (issue 20, point 7):
# each run starts a fresh emulator, switches the servos on, moves all three axes to 30,
# 25 and 50 % of their closed-loop ranges (TMN?..TMX?), polls ONT? every 10 ms (10 s at
# most), then checks #5 and ONT? 20 times 10 ms apart: once ONT? has said on target,
# no axis may be reported moving. Prints one line per run and the totals.
#
# Not part of CI. Needs pipython (`pip install pipython`; its pure-Python socket gateway,
# not PI's GCS DLL) and a built binary. Usage:
#   bash bench/pipython_settle.sh [RUNS=16] [BINARY=target/release/cellinject] [PORT=50300]
set -euo pipefail
cd "$(dirname "$0")/.."
runs=${1:-16}
bin=${2:-target/release/cellinject}
port=${3:-50300}
script=$(mktemp)
trap 'rm -f "$script"' EXIT
cat > "$script" <<'PY'
import sys, time
from pipython.pidevice.interfaces.pisocket import PISocket
from pipython.pidevice.gcsmessages import GCSMessages
from pipython.pidevice.gcscommands import GCSCommands

port = int(sys.argv[1])
fail_ont = fail_mask = 0
settle = []
with PISocket('127.0.0.1', port) as gw, GCSCommands(GCSMessages(gw)) as dev:
    axes = dev.axes
    dev.SVO(axes, [True] * len(axes))
    tmn, tmx = dev.qTMN(axes), dev.qTMX(axes)
    for frac in (0.30, 0.25, 0.50):
        dev.MOV(axes, [tmn[a] + frac * (tmx[a] - tmn[a]) for a in axes])
        t0 = time.monotonic()
        while not all(dev.qONT(axes).values()):
            if time.monotonic() - t0 > 10.0:
                fail_ont += 1
                print(f"  ONT? false 10 s after MOV to {frac}: POS? {dict(dev.qPOS(axes))}")
                break
            time.sleep(0.01)
        else:
            settle.append(time.monotonic() - t0)
        for _ in range(20):
            moving, ont = dev.IsMoving(axes), dev.qONT(axes)
            if any(moving.values()) or not all(ont.values()):
                fail_mask += 1
                print(f"  after ONT? at {frac}: #5 {dict(moving)}, ONT? {dict(ont)}")
                break
            time.sleep(0.01)
    dev.SVO(axes, [False] * len(axes))
print(f"RESULT {fail_ont} {fail_mask} " + " ".join(f"{s:.3f}" for s in settle))
PY
total_ont=0; total_mask=0; failing=0; all_settle=""
for i in $(seq 1 "$runs"); do
  "$bin" emulate gcs --bind "127.0.0.1:$port" --bench none > /dev/null 2>&1 &
  pid=$!
  for _ in $(seq 1 100); do
    (exec 3<>"/dev/tcp/127.0.0.1/$port") 2> /dev/null && break
    sleep 0.1
  done
  out=$(python3 "$script" "$port")
  kill "$pid"; wait "$pid" 2> /dev/null || true
  echo "run $i: $out" | sed 's/^\(run [0-9]*: \)RESULT /\1/'
  read -r o m s <<< "$(echo "$out" | sed -n 's/^RESULT //p')"
  total_ont=$((total_ont + o)); total_mask=$((total_mask + m))
  if [ $((o + m)) -gt 0 ]; then failing=$((failing + 1)); fi
  all_settle="$all_settle $s"
done
echo "$runs runs, $failing failing: ONT? false 10 s $total_ont times, #5 or ONT? disagreeing after ONT? $total_mask times"
echo "$all_settle" | tr ' ' '\n' | sed '/^$/d' | sort -n | awk '{a[NR]=$1} END {if (NR) printf "settle (wall, MOV to ONT? all true): median %.3f s, worst %.3f s, %d moves\n", a[int((NR+1)/2)], a[NR], NR}'
