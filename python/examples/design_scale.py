"""How design evaluations at FEA fidelity scale over Dask workers.

Evaluates N designs whose joint throats all differ (so every evaluation solves its two
joints by the 3-D FEM: nothing comes from the joint cache) serially and on a Dask
LocalCluster of W single-threaded worker processes, and prints the wall time, the
time per evaluation, each worker's peak memory and the projected time on more
workers. Use a release build of the package (`pip install ./python`).

    python python/examples/design_scale.py --designs 1000 --workers 1 2
"""

import argparse
import json
import os
import random
import resource
import sys
import tempfile
import time


def designs(n, seed):
    rng = random.Random(seed)
    return [
        {
            "geometry.b2": rng.uniform(0.14, 0.22),
            "structure.throat_J3": rng.uniform(1.6e-3, 2.6e-3),
            "structure.throat_J12": rng.uniform(1.0e-3, 1.6e-3),
        }
        for _ in range(n)
    ]


def one(variables):
    import cellinject
    from cellinject import design

    try:
        return design.evaluate(variables, fidelity="fea")
    except cellinject.Error as e:
        return str(e)


def peak_rss_bytes():
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--designs", type=int, default=1000)
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    from dask.distributed import Client, LocalCluster

    results = []
    for w in args.workers:
        # A fresh joint cache per run: every joint is solved.
        cache = tempfile.mkdtemp(prefix=f"cellinject-scale-{w}-")
        os.environ["XDG_CACHE_HOME"] = cache
        batch = designs(args.designs, args.seed + w)
        with LocalCluster(n_workers=w, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
            with Client(cluster) as client:
                t = time.perf_counter()
                out = client.gather(client.map(one, batch, pure=False))
                wall = time.perf_counter() - t
                peaks = list(client.run(peak_rss_bytes).values())
        failed = sum(1 for f in out if not isinstance(f, dict))
        r = {
            "workers": w,
            "designs": args.designs,
            "wall_s": wall,
            "per_design_s": wall / args.designs,
            "worker_peak_rss_mb": [p / 1e6 for p in peaks],
            "failed": failed,
        }
        results.append(r)
        print(json.dumps(r), flush=True)
    base = results[0]
    serial = base["wall_s"] * base["workers"]
    print(
        f"projected for {args.designs} designs (perfect scaling from {base['workers']} worker(s)): "
        + ", ".join(f"{n} workers {serial / n / 60:.1f} min" for n in [1, 2, 8, 32, 128]),
        file=sys.stderr,
    )


if __name__ == "__main__":
    main()
