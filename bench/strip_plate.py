#!/usr/bin/env python3
"""A hand-written strip plate with touching doublets, as a lab writes one (issue 36).

    python3 bench/strip_plate.py SEED > strip.toml         # the plate, TOML on stdout
    python3 bench/strip_plate.py --score strip.toml run.json  # a run against it

The plate: 3 x 40 wells, pitch 200 um (several fields of view), 8 wells empty, 5 wells
holding a touching doublet (a 20-30 um cell and a 10 um partner, the pair centred on the
well), every other well one cell of 10-30 um anywhere within 15 um of its centre:
117 cells. Only the standard library; the same SEED gives the same plate.

--score reads `cellinject runs show` JSON and prints each doublet's and each failed
cell's line (true and measured diameter, dose, outcome), then one summary line:
`cells N failed F skipped S partners P worst_partner_um W median_um M`.
"""
import json
import math
import random
import re
import signal
import statistics
import sys

ROWS, COLS, PITCH = 3, 40, 200e-6


def plate(seed):
    rng = random.Random(seed)
    out = [
        f"# A hand-written strip plate with touching doublets (bench/strip_plate.py {seed})",
        "[plate]",
        f"rows = {ROWS}",
        f"cols = {COLS}",
        f"pitch = {PITCH:g}",
        "origin = [0.0, 0.0]",
        "",
    ]
    wells = [(r, c) for r in range(ROWS) for c in range(COLS)]
    rng.shuffle(wells)
    empty, doublets = set(wells[:8]), set(wells[8:13])

    def cell(r, c, x, y, d):
        return ["[[cell]]", f"well = [{r}, {c}]", f"offset = [{x:.3e}, {y:.3e}]", f"diameter = {d:.3e}", ""]

    for r in range(ROWS):
        for c in range(COLS):
            if (r, c) in empty:
                continue
            if (r, c) in doublets:
                big, small = rng.uniform(20e-6, 30e-6), 10e-6
                ang = rng.uniform(0.0, 2.0 * math.pi)
                # Touching: 10 nm apart, which the file's 4 digits keep from overlapping.
                d = (big + small) / 2.0 + 1e-8
                # The pair centred on the well: the big cell's centre a share of d back.
                bx = -math.cos(ang) * d * small / (big + small)
                by = -math.sin(ang) * d * small / (big + small)
                out += cell(r, c, bx, by, big)
                out += cell(r, c, bx + math.cos(ang) * d, by + math.sin(ang) * d, small)
            else:
                d = rng.uniform(10e-6, 30e-6)
                out += cell(r, c, rng.uniform(-15e-6, 15e-6), rng.uniform(-15e-6, 15e-6), d)
    return "\n".join(out)


def score(plate_file, run_file):
    txt = open(plate_file).read()
    pitch = float(re.search(r"pitch = (\S+)", txt).group(1))
    cells = []
    for blk in txt.split("[[cell]]")[1:]:
        w = tuple(int(v) for v in re.search(r"well = \[(\d+), (\d+)\]", blk).groups())
        o = [float(v) for v in re.search(r"offset = \[(\S+), (\S+)\]", blk).groups()]
        d = float(re.search(r"diameter = (\S+)", blk).group(1))
        cells.append((w[1] * pitch + o[0], w[0] * pitch + o[1], d, w))
    per_well = {}
    for c in cells:
        per_well[c[3]] = per_well.get(c[3], 0) + 1
    run = json.load(open(run_file))
    errs, partners = [], []
    failed = skipped = 0
    for a in run["attempts"]:
        x, y, d = a["x_m"], a["y_m"], a["diameter_m"]
        best = min(cells, key=lambda c: (c[0] - x) ** 2 + (c[1] - y) ** 2)
        err = d - best[2]
        errs.append(abs(err))
        doublet = per_well[best[3]] > 1
        if doublet and best[2] < 11e-6:
            partners.append(abs(err))
        failed += a["outcome"] == "failed"
        skipped += a["outcome"] == "skipped"
        if doublet or a["outcome"] != "injected":
            dose = a.get("dose_fraction")
            print(
                f"cell {a['cell']:3d} well {list(best[3])} {'doublet' if doublet else 'single '} "
                f"true {best[2] * 1e6:.1f} um measured {d * 1e6:.1f} um ({err * 1e6:+.2f}) "
                f"dose {'-' if dose is None else f'{dose:.2f}'} alive {a.get('alive')} "
                f"{a['outcome']}: {(a.get('reason') or '')[:90]}"
            )
    print(
        f"cells {len(run['attempts'])} failed {failed} skipped {skipped} partners {len(partners)} "
        f"worst_partner_um {1e6 * max(partners, default=float('nan')):.2f} "
        f"median_um {1e6 * statistics.median(errs):.2f}"
    )


def main(argv):
    if len(argv) == 2 and argv[1] not in ("-h", "--help"):
        try:
            seed = int(argv[1])
        except ValueError:
            print(f"strip_plate.py: SEED must be a whole number, not {argv[1]!r}", file=sys.stderr)
            return 2
        print(plate(seed))
        return 0
    if len(argv) == 4 and argv[1] == "--score":
        try:
            score(argv[2], argv[3])
        except (OSError, ValueError, KeyError) as e:
            print(f"strip_plate.py --score: {e}", file=sys.stderr)
            return 2
        return 0
    if len(argv) == 2:
        print(__doc__.strip())
        return 0
    print(__doc__.strip(), file=sys.stderr)
    return 2


if __name__ == "__main__":
    # A closed pipe (`| head`) ends the output quietly, as for any filter.
    signal.signal(signal.SIGPIPE, signal.SIG_DFL)
    sys.exit(main(sys.argv))
