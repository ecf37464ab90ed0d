"""Time and peak memory of `build_head` per resolution; prints a table.

    python benchmarks/build_model.py --resolution coarse [--resolution paper ...]

Peak memory is the process's maximum resident set size (ru_maxrss), so run one resolution per
process for a clean figure. Never asserted in tests.
"""

from __future__ import annotations

import argparse
import platform
import resource
import time

from facesim.anatomy import build_head


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--resolution", action="append", default=None)
    ap.add_argument("-o", "--out", default=None, help="save the last model here (.npz)")
    args = ap.parse_args()
    rows = []
    for res in args.resolution or ["test"]:
        t = time.perf_counter()
        model = build_head(res, progress=lambda m: print(f"  [{time.perf_counter() - t:7.1f} s] {m}", flush=True))
        wall = time.perf_counter() - t
        peak_gb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024 ** 2
        q = model.meta["quality"]
        rows.append((res, model.n_nodes, model.n_tets, model.n_simulated, wall, model.meta["timings"]["tetwild_s"],
                     peak_gb, q["min_dihedral_deg"], q["worst_volume_ratio"]))
        if args.out:
            model.save(args.out)
    print(f"\nmachine: {platform.machine()} {platform.processor() or ''}, python {platform.python_version()}")
    print(f"{'resolution':>10} {'nodes':>8} {'tets':>8} {'simulated':>9} {'build s':>8} {'tetwild s':>9} "
          f"{'peak GB':>8} {'min dih':>8} {'worst VR':>8}")
    for r in rows:
        print(f"{r[0]:>10} {r[1]:>8} {r[2]:>8} {r[3]:>9} {r[4]:>8.1f} {r[5]:>9.1f} {r[6]:>8.2f} {r[7]:>8.1f} {r[8]:>8.3f}")


if __name__ == "__main__":
    main()
