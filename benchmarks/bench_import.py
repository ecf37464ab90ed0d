"""`facesim model import` on the Badin face: time and peak memory of each route, one table.

    NUMBA_NUM_THREADS=2 python benchmarks/bench_import.py [--anatomy DIR] [--out DIR]

Each route runs in its own process (`facesim model import ... -q`), so its peak resident memory
(``ru_maxrss`` of the child) is its own: the volume route (``flesh.vtu``, re-meshed from its
boundary since its split hexes are slivers; and with ``--remesh no``, the given mesh) and the
surfaces route (the skin taken as the volume's boundary, written as an OBJ). Per run: wall time,
the import's own stage timings (``meta["import"]["timings"]``), peak memory, nodes, tets, the
smallest dihedral angle and the flagged muscles. Timings are never asserted; record the table in
benchmarks/RESULTS.md.
"""

from __future__ import annotations

import argparse
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]


def _run(argv, env) -> tuple[float, float]:
    """Wall seconds and peak RSS (MB) of ``facesim argv``, run under a fresh intermediate process
    whose only child it is (``ru_maxrss`` of RUSAGE_CHILDREN is the largest child's)."""
    probe = ("import resource, subprocess, sys; r = subprocess.run([sys.executable, '-m', 'facesim', *sys.argv[1:]], "
             "capture_output=True, text=True); sys.stderr.write(r.stderr); "
             "print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss); sys.exit(r.returncode)")
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-c", probe, *argv], env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if proc.returncode:
        raise SystemExit(f"facesim {' '.join(argv)} failed:\n{proc.stderr}")
    return wall, int(proc.stdout.split()[-1]) / 1024.0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--anatomy", default=str(REPO.parent / "shared" / "anatomy" / "badin"))
    ap.add_argument("--out", default=None)
    args = ap.parse_args(argv)
    import trimesh

    from facesim.importing.meshes import read_volume, volume_boundary
    from facesim.model import load_model

    A = Path(args.anatomy)
    out = Path(args.out or tempfile.mkdtemp(prefix="bench_import_"))
    out.mkdir(parents=True, exist_ok=True)
    vol = read_volume(A / "flesh.vtu")
    F = volume_boundary(vol.X, vol.tets)
    used, inv = np.unique(F, return_inverse=True)
    trimesh.Trimesh(vol.X[used], inv.reshape(-1, 3), process=False).export(out / "skin.obj")
    bones = ["--mandible", str(A / "mandible.obj"), "--cranium", str(A / "maxilla.obj"),
             "--teeth-upper", str(A / "teeth_upper.obj"), "--teeth-lower", str(A / "teeth_lower.obj")]
    runs = [("volume (re-meshed, 8 mm)", ["--flesh", str(A / "flesh.vtu")]),
            ("volume (given mesh)", ["--flesh", str(A / "flesh.vtu"), "--remesh", "no"]),
            ("surfaces (8 mm)", ["--skin", str(out / "skin.obj")])]
    env = {**os.environ, "NUMBA_NUM_THREADS": os.environ.get("NUMBA_NUM_THREADS", "2")}
    print(f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores; Badin face from {A}; out {out}")
    rows = []
    for name, route in runs:
        path = out / (name.split()[0] + ("_given" if "given" in name else "") + ".npz")
        wall, peak = _run(["model", "import", "-o", str(path), *route, *bones, "-q"], env)
        m = load_model(path)
        rep = m.meta["import"]
        rows.append((name, wall, rep["timings"], peak, m.n_nodes, m.n_tets, rep["quality"]["min_dihedral_deg"],
                     len(rep["template"]["muscles"]["flagged"])))
    print("| route | wall s | mesh s | template s | peak MB | nodes | tets | min dihedral deg | flagged muscles |")
    print("|---|---|---|---|---|---|---|---|---|")
    for name, wall, t, peak, n, m, dih, flagged in rows:
        print(f"| {name} | {wall:.1f} | {t.get('mesh', 0):.1f} | {t.get('template', 0):.1f} | {peak:.0f} | {n:,} | "
              f"{m:,} | {dih:.1f} | {flagged} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
