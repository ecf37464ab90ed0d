"""Contact in the inverse solver (issue 13): a pressed-lips capture (orbicularis oris 0.3 -> 1.0,
mentalis, jaw closed) simulated with lip and teeth contact on SRC, solved on DST with and without
contact; prints per frame the solver counts, seconds and the lip/teeth penetration (frames.csv).

    python benchmarks/bench_contact_inverse.py [SRC.npz] [DST.npz] [FRAMES] [OUT_DIR]
"""
import sys
import time

import numpy as np

from facesim import Simulation, load_model
from facesim.fem.equilibrium import EquilibriumOptions, FaceSimulator
from facesim.inverse.tracking import TrackOptions, track

src = sys.argv[1] if len(sys.argv) > 1 else "meshes/face_coarse.npz"
dst = sys.argv[2] if len(sys.argv) > 2 else "meshes/face_coarse.npz"
n = int(sys.argv[3]) if len(sys.argv) > 3 else 3
out = sys.argv[4] if len(sys.argv) > 4 else "bench_contact_inverse"
truth_model = load_model(src)
sim = Simulation(truth_model, jaw_model="sliding-condyle", teeth_contact=True, lip_contact=True)
levels = np.linspace(0.3, 1.0, n)
P = []
t = time.time()
for k, lv in enumerate(levels):
    f = sim.step({"orbicularis_oris_upper": lv, "orbicularis_oris_lower": lv, "mentalis": 0.3 * lv}, jaw=np.zeros(3), frame=k)
    print("truth", k, f.converged, f.iterations, f.measures, f"{f.seconds:.1f}s", flush=True)
    P.append(f.markers)
print("truth total", time.time() - t)
P = np.array(P)
model = load_model(dst)
for contact in (True, False):
    opts = EquilibriumOptions(lip_contact=contact, teeth_contact=contact)
    fs = FaceSimulator(model, opts, jaw_model="sliding-condyle")
    t = time.time()
    s = track(fs, np.arange(n), P, f"{out}/contact_{contact}", options=TrackOptions(head="none"), progress=False,
              overwrite=True)
    rows = open(f"{out}/contact_{contact}/frames.csv").read()
    print("contact", contact, f"{time.time()-t:.1f}s", s["stop_reasons"], s["marker_rms"])
    print(rows)
