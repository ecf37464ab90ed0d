"""``build_head``: the procedural anatomical face model, from implicit anatomy to :class:`FaceModel`."""

from __future__ import annotations

import dataclasses
import time

import numpy as np
import trimesh

from facesim.anatomy import meshing, phantom, sdf
from facesim.anatomy.markers import bind_markers
from facesim.anatomy.muscles import embed_muscles
from facesim.anatomy.quality import quality_summary
from facesim.errors import FacesimError
from facesim.model import FaceModel, RigidSurface, Tissue

#: resolution -> (field grid spacing mm, target edge in the simulated face mm, target edge
#: elsewhere mm, fTetWild envelope as a fraction of the bounding-box diagonal). The envelope
#: decides the tet count at low resolution: thin layers (lids, lips, mouth lining) force small
#: tets unless the surface may move by up to epsilon * ~330 mm.
RESOLUTIONS = {
    "test": (1.0, 14.0, 20.0, 4.0e-3),
    "coarse": (1.0, 9.0, 17.0, 3.0e-3),
    "medium": (1.0, 5.5, 10.0, 2.5e-3),
    "paper": (0.8, 2.5, 7.0, 1.5e-3),
}

#: Mooney-Rivlin constants (MPa): initial shear modulus 5.4 kPa for flesh, inside the 2.5-60 kPa
#: published for facial soft tissue (docs/physics.md section 1), kappa / mu ~ 24 (nu ~ 0.48).
TISSUES = (
    Tissue("flesh", c10=2.0e-3, c01=0.7e-3, kappa=0.13),
    Tissue("lip", c10=1.5e-3, c01=0.5e-3, kappa=0.1),
    Tissue("nose_cartilage", c10=2.0e-2, c01=0.8e-2, kappa=1.4),
)
FLESH, LIP, NOSE = range(3)


def simulated_region(sub: phantom.Subject):
    """Predicate on points ``(k, 3)``: inside the simulated face region (in front of the ears,
    above the lower neck, below the upper forehead)."""
    def inside(p):
        p = np.asarray(p) / np.array([sub.width, sub.height, sub.depth])
        r = phantom.FACE_REGION
        return (p[:, 2] > r["z_min"] - 1.0) & (p[:, 1] > r["y_min"] - 1.0) & (p[:, 1] < r["y_max"] + 1.0)
    return inside


def _tissue_labels(centroids: np.ndarray, sub: phantom.Subject) -> np.ndarray:
    c = centroids / np.array([sub.width, sub.height, sub.depth])
    t = np.full(len(c), FLESH, np.int32)
    lip = (np.abs(c[:, 0]) < 28) & (c[:, 1] > -54) & (c[:, 1] < -27) & (c[:, 2] > 80)
    nose = (np.abs(c[:, 0]) < 22) & (c[:, 1] > -16) & (c[:, 1] < 22) & (c[:, 2] > 93 + 0.35 * (c[:, 1] + 16))
    t[lip] = LIP
    t[nose] = NOSE
    return t


def _rigid_surface(name, bone, field, grid, stride=2, smooth=0.6) -> RigidSurface:
    """Closed surface of ``field`` sampled every ``stride`` grid cells (keeps files small)."""
    g = sdf.Grid(tuple(grid.lo), grid.h * stride, tuple(len(range(0, s, stride)) for s in grid.shape))
    v, f = meshing.isosurface(np.ascontiguousarray(field[::stride, ::stride, ::stride]), g, smooth_mm=smooth)
    return RigidSurface(name, bone, v, f)


def _sphere_surface(name, bone, centre, radius) -> RigidSurface:
    m = trimesh.creation.icosphere(subdivisions=3, radius=radius)
    return RigidSurface(name, bone, m.vertices + centre, m.faces)


def measure_depths(X: np.ndarray, skin: np.ndarray, fields: phantom.HeadFields, sub: phantom.Subject) -> dict:
    """Soft-tissue depth (mm) at each landmark of :data:`phantom.DEPTH_LANDMARKS`.

    From the bone (or tooth) surface point on the landmark's line, along its outward direction,
    to the first crossing of the outer skin: ``depth_mm`` on the meshed skin ``(X, skin)``,
    ``anatomy_depth_mm`` on the skin field (the anatomy before meshing; the mesh follows it to
    within the fTetWild envelope).
    """
    g = fields.grid
    hard = np.minimum(np.minimum(fields.cranium_skull, fields.jaw), np.minimum(fields.teeth_upper, fields.teeth_lower))
    mesh = trimesh.Trimesh(X, skin, process=False)
    out = {}
    for name, p, n, _, rng in phantom.DEPTH_LANDMARKS:
        n = np.asarray(n, float) / np.linalg.norm(n)
        p = sub.scaled(p)
        s = np.linspace(-25, 25, 5001)
        val = g.sample(hard, p + s[:, None] * n)
        outside = val > 0
        # last inside->outside crossing before the skin: the bone surface
        idx = np.flatnonzero(~outside[:-1] & outside[1:])
        if not len(idx):
            raise FacesimError(f"depth landmark {name}: no bone surface found along its direction")
        i = idx[-1]
        t = s[i] + (s[i + 1] - s[i]) * val[i] / (val[i] - val[i + 1])
        bone_pt = p + t * n
        loc, _, _ = mesh.ray.intersects_location([bone_pt + 0.01 * n], [n])
        if not len(loc):
            raise FacesimError(f"depth landmark {name}: the skin is not reached along its direction")
        d = np.min(np.linalg.norm(loc - bone_pt, axis=1))
        s2 = np.linspace(0.0, 40.0, 8001)
        sk = g.sample(fields.skin, bone_pt + s2[:, None] * n)
        j = np.flatnonzero((sk[:-1] < 0) & (sk[1:] >= 0))
        d_field = float(s2[j[0]] + (s2[j[0] + 1] - s2[j[0]]) * -sk[j[0]] / (sk[j[0] + 1] - sk[j[0]])) if len(j) \
            else float("nan")
        out[name] = {"depth_mm": float(d), "anatomy_depth_mm": d_field, "range_mm": list(rng),
                     "bone_point": bone_pt.tolist(), "direction": n.tolist()}
    return out


def build_head(resolution: str = "coarse", seed: int = 0, progress=None, threads: int = 0,
               mesh: tuple[np.ndarray, np.ndarray] | None = None, subject: phantom.Subject | None = None) -> FaceModel:
    """Build the procedural anatomical face model.

    Parameters
    ----------
    resolution : ``"test"`` (a few thousand tets, for tests), ``"coarse"`` (~20-30K simulated
        tets), ``"medium"`` (~100K) or ``"paper"`` (>= 350K simulated tets, Sifakis 2005 size).
    seed : 0 gives the canonical head; other seeds perturb the proportions reproducibly.
    progress : optional callable taking a one-line status message.
    threads : fTetWild threads (0 = all cores).
    mesh : optional ``(X (n, 3) float64, tets (m, 4) int32)`` tet mesh of the flesh to reuse
        (e.g. from an earlier model of the same seed and resolution) instead of running fTetWild.
    subject : optional explicit :class:`~facesim.anatomy.phantom.Subject` proportions (width,
        jaw length, soft-tissue depth, ...) instead of the seed's; ``seed`` is then only recorded.

    The anatomy, fields and surfaces are deterministic for a given seed and resolution; the
    tetrahedralisation (fTetWild) is not bit-reproducible between runs (wildmeshing/fTetWild#72),
    and every array derived from a given tet mesh is: rebuilding with ``mesh`` taken from a
    model reproduces that model exactly.
    """
    if resolution not in RESOLUTIONS:
        raise FacesimError(f"resolution: expected one of {', '.join(RESOLUTIONS)}, got {resolution!r}")
    say = progress or (lambda msg: None)
    timings = {}
    t0 = time.perf_counter()

    def lap(key):
        nonlocal t0
        t = time.perf_counter()
        timings[key] = round(t - t0, 2)
        t0 = t

    h, edge_face, edge_back, epsilon = RESOLUTIONS[resolution]
    sub = phantom.subject_from_seed(int(seed)) if subject is None else subject
    fields = phantom.build_fields(sub, h=h, progress=lambda m: say(f"fields: {m}"))
    lap("fields_s")
    say("flesh surface")
    v, f = meshing.isosurface(fields.flesh, fields.grid, smooth_mm=0.5)
    lap("surface_s")
    sim_fn = simulated_region(sub)
    if mesh is None:
        say(f"tetrahedralising with fTetWild (edge {edge_face} mm in the face, {edge_back} mm elsewhere)")
        X, T = meshing.tetrahedralise(v, f, edge_face, edge_back, sim_fn, epsilon=epsilon, threads=threads)
    else:
        say("reusing the given tet mesh")
        X, T = meshing.check_tet_mesh(*mesh)
    lap("tetwild_s")
    say(f"labelling {len(T)} tets")
    L = meshing.label_mesh(X, T, fields, sim_fn)
    skin_lab = meshing.label_boundary(X, L.skin, fields)
    outer = skin_lab == meshing.SKIN
    mouth_lab = skin_lab == meshing.MOUTH
    c = X[L.skin].mean(axis=1)
    cs = c / np.array([sub.width, sub.height, sub.depth])
    mouth = mouth_lab & (cs[:, 2] > 52) & (np.abs(cs[:, 0]) < 45) & (cs[:, 1] > -62) & (cs[:, 1] < -20)
    stom = phantom.stomion_y(sub) + 0.004 * c[:, 0] ** 2
    lip_upper = L.skin[mouth & (c[:, 1] > stom)]
    lip_lower = L.skin[mouth & (c[:, 1] <= stom)]
    tissue = _tissue_labels(X[T].mean(axis=1), sub)
    lap("labels_s")
    say("embedding 32 muscles")
    muscles, _ = embed_muscles(X, T, fields.skin, fields.grid, scale=sub.scaled)
    lap("muscles_s")
    say("binding markers")
    markers = bind_markers(X, L.skin, outer, scale=sub.scaled)
    say("bone and collider surfaces")
    arches = phantom.dental_arches(sub)
    bones = (_rigid_surface("cranium", "cranium", fields.cranium_skull, fields.grid),
             _rigid_surface("mandible", "jaw", fields.jaw, fields.grid, stride=1, smooth=0.5))
    eye = sub.scaled(phantom.EYE_CENTRE)
    colliders = (_rigid_surface("upper_teeth", "cranium", fields.teeth_upper, fields.grid, stride=1, smooth=0.0),
                 _rigid_surface("lower_teeth", "jaw", fields.teeth_lower, fields.grid, stride=1, smooth=0.0),
                 _sphere_surface("eye_L", "cranium", eye, phantom.EYE_RADIUS),
                 _sphere_surface("eye_R", "cranium", eye * np.array([-1.0, 1.0, 1.0]), phantom.EYE_RADIUS))
    jaw = phantom.jaw_geometry(sub, arches)
    say("measuring soft-tissue depths and mesh quality")
    depths = measure_depths(X, L.skin[outer], fields, sub)
    quality = quality_summary(X, T)
    lap("surfaces_markers_s")
    meta = {
        "builder": "facesim.anatomy.build_head",
        "resolution": resolution,
        "seed": int(seed),
        "subject": dataclasses.asdict(sub),
        "grid_mm": h,
        "edge_face_mm": edge_face,
        "edge_back_mm": edge_back,
        "envelope": epsilon,
        "envelope_mm": float(epsilon * np.linalg.norm(v.max(0) - v.min(0))),
        "mesher": "pytetwild (fTetWild)" if mesh is None else "reused tet mesh",
        "timings": timings,
        "quality": quality,
        "soft_tissue_depths": depths,
        "rigid_core_depth_mm": phantom.CORE_DEPTH,
        "rigid_core_clearance_mm": dict(phantom.CORE_CLEARANCE),
        "units": "mm, N, MPa",
    }
    return FaceModel(X=X, tets=T, tissue=tissue, tissues=TISSUES, simulated=L.simulated, muscles=muscles,
                     cranium_nodes=L.cranium_nodes, jaw_nodes=L.jaw_nodes, skin=L.skin, lip_upper=lip_upper,
                     lip_lower=lip_lower, bones=bones, colliders=colliders, markers=markers, jaw=jaw, meta=meta)
