"""The tracked objects: upper and lower teeth in mm in facesim's frame, and their incisal points.

Teeth come from the shipped model (its rigid colliders ``upper_teeth`` / ``lower_teeth``,
already in facesim's frame) or from any mesh files trimesh or meshio reads, in any units and
frame. For files the importer's machinery is reused:

* units: :func:`facesim.importing.meshes.infer_units` on both dentitions together (``--units
  auto``; a dentition spans 60-80 mm, inside a face region's range) or as given;
* frame (facesim's: x the subject's left, y up, z forward, origin between the condyles):
  with the mandible (``--mandible``) the importer's :func:`~facesim.importing.frame.anatomical_frame`
  (symmetry plane, landmarks matched to the template's, origin at the condyles); with the teeth
  alone :func:`teeth_frame`: the symmetry plane of the teeth, up normal to their occlusal plane
  tilted as the template's, forward toward the incisors, and the origin placed so the lower
  incisal point sits where the template's does (the condyles are unknown without a mandible);
  ``--frame SPEC`` gives the axes instead (as ``facesim model import --frame``).

The lower incisal point (the top of the lower teeth's midline, :mod:`facesim.importing.landmarks`)
is the reference point of the poses ``facesim teeth track`` writes, so ``facesim jaw fit`` reads
them in the frame it expects (mm, mandible relative to skull, rest = identity).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np

from facesim.errors import FacesimError

#: Mandible points kept in a poses file (an even subset of the lower teeth's vertices).
MANDIBLE_POINTS = 800


@dataclass(frozen=True)
class Dentition:
    """Upper and lower teeth at rest.

    upper_V, lower_V : (n, 3) float64 vertices, mm, facesim's frame (the world at rest).
    upper_F, lower_F : (m, 3) int32 triangles.
    incisor : (3,) mm, the lower incisal point (the jaw's reference point).
    upper_incisor : (3,) mm, the upper incisal point.
    source : dict, where the teeth came from (files, units, frame cues), JSON-serialisable.
    """

    upper_V: np.ndarray
    upper_F: np.ndarray
    lower_V: np.ndarray
    lower_F: np.ndarray
    incisor: np.ndarray
    upper_incisor: np.ndarray
    source: dict = field(default_factory=dict)

    def merged(self) -> tuple[np.ndarray, np.ndarray, int]:
        """``(V (n, 3), F (m, 3) int32, n_upper_faces)``: both dentitions in one mesh, upper first
        (a face index below ``n_upper_faces`` is an upper tooth)."""
        V = np.concatenate([self.upper_V, self.lower_V])
        F = np.concatenate([self.upper_F, self.lower_F + len(self.upper_V)]).astype(np.int32)
        return V, F, len(self.upper_F)

    def mandible_points(self, count: int = MANDIBLE_POINTS) -> np.ndarray:
        """``(count, 3)`` mm: an even subset of the lower teeth's vertices (the points a poses
        file measures its errors on)."""
        from facesim.importing.frame import _even_subset

        return _even_subset(self.lower_V, min(count, len(self.lower_V)))

    def save_obj(self, folder) -> tuple:
        """Write ``teeth_upper.obj`` and ``teeth_lower.obj`` (mm, facesim's frame) into ``folder``."""
        from pathlib import Path

        from facesim._files import atomic_write

        out = []
        for name, V, F in (("teeth_upper", self.upper_V, self.upper_F), ("teeth_lower", self.lower_V, self.lower_F)):
            text = "# facesim teeth, mm, facesim frame (x left, y up, z forward)\n" + \
                "".join(f"v {x:.6f} {y:.6f} {z:.6f}\n" for x, y, z in V) + \
                "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in F)
            out.append(atomic_write(Path(folder) / f"{name}.obj", lambda tmp, t=text: tmp.write_text(t)))
        return tuple(out)


def incisal_points(upper_V, upper_F, lower_V, lower_F, x_mid: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """``(lower incisal point, upper incisal point)`` (3,) mm of teeth in facesim's frame whose
    midline is the plane x = ``x_mid`` (:mod:`facesim.importing.landmarks`)."""
    from facesim.importing import landmarks as lm

    points = []
    for V, F, down, what in ((lower_V, lower_F, False, "lower"), (upper_V, upper_F, True, "upper")):
        mid = lm.midline(lm.Mesh(V, F), x_mid)
        if len(mid) < 3:
            raise FacesimError(f"{what} teeth: no midline at x = {x_mid:.1f} mm (are they a whole dentition in "
                               f"facesim's frame? try --frame or --mandible)")
        points.append(lm._incisal(mid, x_mid, down=down))
    return points[0], points[1]


def shipped_dentition() -> Dentition:
    """The teeth of the shipped model ``meshes/face_coarse.npz`` (its colliders ``upper_teeth``
    and ``lower_teeth``)."""
    from facesim.jaw._shipped import shipped_model

    model = shipped_model()
    parts = {c.name: c for c in model.colliders}
    if "upper_teeth" not in parts or "lower_teeth" not in parts:
        raise FacesimError("the shipped model has no upper_teeth / lower_teeth colliders")
    u, lo = parts["upper_teeth"], parts["lower_teeth"]
    uV, uF = np.asarray(u.vertices, dtype=np.float64), np.asarray(u.faces, dtype=np.int32)
    lV, lF = np.asarray(lo.vertices, dtype=np.float64), np.asarray(lo.faces, dtype=np.int32)
    inc, up = incisal_points(uV, uF, lV, lF)
    return Dentition(uV, uF, lV, lF, inc, up, {"teeth": "shipped model meshes/face_coarse.npz", "units": "mm",
                                               "frame": "facesim"})


@lru_cache(maxsize=1)
def _template_geometry():
    """(template incisor (3,) mm, template occlusal tilt degrees) of the shipped model."""
    from facesim.importing import landmarks as lm
    from facesim.importing.frame import _occlusal_tilt

    d = shipped_dentition()
    tilt = _occlusal_tilt(lm.Mesh(d.upper_V, d.upper_F), lm.Mesh(d.lower_V, d.lower_F))
    return d.incisor, 0.0 if tilt is None else tilt


def teeth_frame(upper, lower, scale: float, spec: str | None = None) -> tuple[np.ndarray, list[str]]:
    """``(T (4, 4), cues)``: the rigid map from the teeth surfaces' coordinates scaled to mm to
    facesim's frame, from the teeth alone (see the module docstring), or with the axes of
    ``spec`` (:func:`facesim.importing.frame.parse_frame_spec`)."""
    from facesim.importing import landmarks as lm
    from facesim.importing.frame import _occlusal_tilt, _rotate_about_left, parse_frame_spec, symmetry_plane
    from facesim.importing.meshes import sample_surface

    U, L = scale * upper.vertices, scale * lower.vertices
    cues = []
    if spec is not None:
        R = parse_frame_spec(spec)
        cues.append(f"axes from --frame {spec!r}")
    else:
        samples = [sample_surface(s, spacing=1.0 / scale) for s in (upper, lower)]
        n, d, rms = symmetry_plane([scale * p for p, _ in samples], normals=[q for _, q in samples])
        cues.append(f"symmetry plane of the teeth (mirror RMS {rms:.2f} mm)")
        # the occlusal plane: teeth points within 3 mm of the other dentition (as the importer)
        from scipy.spatial import cKDTree

        du, _ = cKDTree(L).query(U)
        dl, _ = cKDTree(U).query(L)
        gap = min(du.min(), dl.min())
        P = np.concatenate([U[du < gap + 3.0], L[dl < gap + 3.0]])
        _, vecs = np.linalg.eigh(np.cov((P - P.mean(axis=0)).T))
        up = vecs[:, 0] - (vecs[:, 0] @ n) * n
        up /= np.linalg.norm(up)
        if up @ (U.mean(axis=0) - L.mean(axis=0)) < 0:
            up = -up
        A = np.concatenate([U, L])
        mid = A[np.abs(A @ n - d) < 3.0]          # the arch crosses the midline only at the incisors
        if len(mid) < 10:
            raise FacesimError("teeth: the midline of the dental arch could not be found; give --frame or --mandible")
        fwd = mid.mean(axis=0) - A.mean(axis=0)
        fwd = fwd - (fwd @ n) * n - (fwd @ up) * up
        fwd /= np.linalg.norm(fwd)
        R = np.stack([np.cross(up, fwd), up, fwd])
        T0 = np.eye(4)
        T0[:3, :3] = R
        own = _occlusal_tilt(lm.Mesh(U @ R.T, upper.faces), lm.Mesh(L @ R.T, lower.faces)) or 0.0
        _, template_tilt = _template_geometry()
        for sign in (1.0, -1.0):   # the tilt's sign convention: keep the rotation that matches
            Rs = _rotate_about_left(R, sign * np.deg2rad(template_tilt - own))
            got = _occlusal_tilt(lm.Mesh(U @ Rs.T, upper.faces), lm.Mesh(L @ Rs.T, lower.faces)) or 0.0
            if abs(got - template_tilt) < 0.5:
                R = Rs
                break
        cues.append(f"up normal to the occlusal plane, tilted {template_tilt:+.1f} deg as the template's; forward "
                    "toward the incisors")
    # origin: the lower incisal point where the template has it (no condyles without a mandible)
    x_mid = float(np.median((np.concatenate([U, L]) @ R.T)[:, 0])) if spec is not None else None
    Uf, Lf = U @ R.T, L @ R.T
    if x_mid is None:
        x_mid = float(np.mean(np.concatenate([Uf, Lf])[np.abs(np.concatenate([U, L]) @ n - d) < 3.0][:, 0]))
    inc, _ = incisal_points(Uf, upper.faces, Lf, lower.faces, x_mid)
    template_incisor, _ = _template_geometry()
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = template_incisor - inc
    cues.append("origin: the lower incisal point placed at the template's (no mandible given)")
    return T, cues


def read_dentition(upper, lower, units: str = "auto", frame: str = "auto", mandible=None) -> Dentition:
    """The teeth of the files ``upper`` and ``lower`` (any format trimesh or meshio reads) in mm
    in facesim's frame; ``units`` auto|m|cm|mm; ``frame`` ``"auto"`` (from the anatomy), a spec
    such as ``"x=backward,z=up"``, or ``"facesim"`` (the files are already in facesim's frame);
    ``mandible`` an optional mandible file (the importer's frame, origin at its condyles)."""
    from facesim.importing.frame import anatomical_frame
    from facesim.importing.meshes import infer_units, read_surface

    U, L = read_surface(upper, "teeth_upper"), read_surface(lower, "teeth_lower")
    M = read_surface(mandible, "mandible") if mandible is not None else None
    pts = np.concatenate([U.vertices, L.vertices] + ([M.vertices] if M is not None else []))
    scale, unit_name, unit_how = infer_units(pts, units, source=f"{U.name} and {L.name}")
    spec = None if frame in ("auto", "facesim") else frame
    if frame == "facesim":
        T, cues = np.eye(4), ["the files are in facesim's frame (--frame facesim)"]
    elif M is not None:
        fit = anatomical_frame(M, teeth_upper=U, teeth_lower=L, scale_to_mm=scale, units=unit_name, spec=spec)
        T, cues = fit.T, list(fit.cues)
    else:
        T, cues = teeth_frame(U, L, scale, spec)
    uV = (scale * U.vertices) @ T[:3, :3].T + T[:3, 3]
    lV = (scale * L.vertices) @ T[:3, :3].T + T[:3, 3]
    uF, lF = U.faces.astype(np.int32), L.faces.astype(np.int32)
    inc, up = incisal_points(uV, uF, lV, lF)   # every route puts the midline at x = 0
    source = {"upper": str(upper), "lower": str(lower), "mandible": None if mandible is None else str(mandible),
              "units": unit_name, "units_how": unit_how, "T_facesim_from_input_mm": np.round(T, 9).tolist(),
              "frame_cues": cues}
    return Dentition(uV, uF, lV, lF, inc, up, source)


__all__ = ["Dentition", "incisal_points", "read_dentition", "shipped_dentition", "teeth_frame"]
