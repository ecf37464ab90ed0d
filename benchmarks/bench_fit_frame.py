"""One frame of the inverse problem on the shipped coarse face: markers of a known expression
(smile, eye squint, lower-lip depressor, jaw 0.1 rad on the natural sliding-condyle path) with
0.5 mm Gaussian noise per coordinate, fitted from the neutral face.

    python benchmarks/bench_fit_frame.py

Prints GN steps, equilibria, Newton iterations, marker RMS, worst bound violation, seconds,
the objective per step and the activation / jaw errors. (Markers from the same mesh: the
finer-mesh recovery of issue 5 is still to come.)
"""
import numpy as np, time
from facesim.model import load_model
from facesim.fem.equilibrium import FaceSimulator, EquilibriumOptions
from facesim.controls import Controls
from facesim.kinematics.condyle import SlidingCondyleJaw
from facesim.inverse import fit_frame, FitOptions
from facesim.session import activation_vector
m=load_model(str(__import__('pathlib').Path(__file__).resolve().parents[1] / 'meshes' / 'face_coarse.npz'))
jaw=SlidingCondyleJaw(m.jaw)
sim=FaceSimulator(m, jaw_model=jaw)
a=activation_vector(m,{"zygomaticus_major":0.6,"orbicularis_oculi":0.3,"depressor_labii_inferioris":0.3})
truth=Controls(a, jaw=jaw.natural_parameters(0.1))
t=time.time(); eq=sim.equilibrium(truth); print('truth eq', eq.iterations, round(time.time()-t,1), flush=True)
rng=np.random.default_rng(0)
T=m.marker_positions(eq.x)+0.5*rng.normal(size=(m.n_markers,3))
t=time.time()
fit=fit_frame(sim, T, Controls(np.zeros(m.n_muscles), jaw=np.zeros(3)), options=FitOptions(noise=0.5))
r=fit.report
print('fit', r.gn_steps, r.equilibria, r.newton_iterations, 'rms', round(r.marker_rms,3), 'viol', r.worst_violation, round(time.time()-t,1), flush=True)
print('objective', [round(o,2) for o in r.objective], 'alpha', [round(s,2) for s in r.step_lengths])
err=np.abs(fit.controls.a-a); print('act err max', err.max().round(3), 'mean', err.mean().round(3), 'jaw', np.round(fit.controls.jaw,3), 'truth', np.round(truth.jaw,3))
