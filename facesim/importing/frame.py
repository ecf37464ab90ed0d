"""The anatomical frame of an imported face: the rigid transform from the user's coordinates
(scaled to mm) to facesim's frame (x the subject's left, y up, z forward; origin the midpoint of
the condyles).

Found from the anatomy (:func:`anatomical_frame`):

1. *Left-right*: the symmetry plane of the mandible, the teeth, the skin and the cranium parts,
   each registered to its own mirror image (:func:`symmetry_plane`): the best of the principal
   axes and a sphere of candidate normals, refined by iterating "mirror, match each point to
   the nearest point of the same surface, fit the plane that best swaps the pairs" (the
   symmetry ICP of Mitra et al. 2006 in its simplest form).
2. *A first up and forward* in that plane from the mandible alone: the condyles are the
   mandible's points farthest from its midline (symphysis) part, on each side; the chin lies
   forward and down from them, by ``CHIN_ANGLE_DEG`` below forward in the template, and the
   mandible's body lies below the line from the condyles to the chin.
3. *Refinement*: the bone landmarks are found in the current frame
   (:func:`facesim.importing.landmarks.bone_landmarks`), the origin moved to the midpoint of the
   condyles, and the frame turned about the left axis so that the directions from the condyles
   to the incisal points, the pogonion and the menton match the template's best (a weighted
   circular mean of the angle differences, the upper incisor weighted most: it does not move
   with the jaw); repeated until it turns less than 0.01 degree.
   facesim's "up" is thus defined by the template (the procedural head): for the Badin head,
   whose own frame is close to the Frankfurt horizontal, it agrees with that frame to ~1 degree.
   The dental occlusal plane, which real faces tilt 5-10 degrees to the Frankfurt horizontal (the
   template's is level), is reported (``occlusal_deg``), not used.
4. Right-handedness: left = up x forward.

A user spec (:func:`parse_frame_spec`, ``--frame "x=-forward,y=left,z=up"``) replaces steps 1-3
for the axes; the origin is still the condyles' midpoint.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
from scipy.spatial import cKDTree

from facesim.errors import FacesimError
from facesim.importing import landmarks as lm
from facesim.importing.meshes import Surface, sample_surface

#: The chin (mean of the mandible's midline points) below forward, seen from the condyles'
#: midpoint, degrees; in the template ~42 (Badin ~42). Only the first guess uses it.
CHIN_ANGLE_DEG = 42.0
#: The template's bone landmarks (mm, relative to its condyles' midpoint; y up, z forward), as
#: found by facesim.importing.landmarks on meshes/face_coarse.npz (tests/importing/test_frame.py
#: checks they still are): the refinement turns the frame so the subject's directions to them
#: match these, with these weights.
TEMPLATE_SAGITTAL = {"upper_incisor": (-37.14, 80.74), "incisor": (-39.56, 78.41), "pogonion": (-75.52, 80.49),
                     "menton": (-86.39, 73.03)}
#: The same for the incisal points found on bone when no teeth are given (infradentale, prosthion).
TEMPLATE_SAGITTAL_BONE = {"incisor": (-51.56, 79.39), "upper_incisor": (-22.37, 82.10)}
SAGITTAL_WEIGHTS = {"upper_incisor": 2.0, "incisor": 1.0, "pogonion": 0.5, "menton": 0.5}
#: Symmetry fit: points per surface in the cost, the distance (mm) beyond which a mirrored point
#: counts as unmatched, the surface sampling (mm).
SYMMETRY_POINTS = 1500
SYMMETRY_TRIM_MM = 5.0
#: Candidate mirror normals over the sphere (~5 degrees apart) and the matching distances (mm)
#: of the refinement's iterations, coarse to fine (a normal a few degrees off moves a point
#: 60 mm from the plane by ~5 mm).
SYMMETRY_CANDIDATES = 600
SYMMETRY_TRIMS = (15.0, 10.0, 7.0, 5.0, 4.0, 3.0) + (2.5,) * 30
SAMPLE_MM = 1.5
TEETH_WEIGHT = 0.25
#: The anatomical directions of a frame spec and their facesim axes (row of R, sign).
DIRECTIONS = {"left": (0, 1.0), "right": (0, -1.0), "up": (1, 1.0), "down": (1, -1.0), "forward": (2, 1.0),
              "front": (2, 1.0), "anterior": (2, 1.0), "backward": (2, -1.0), "back": (2, -1.0),
              "posterior": (2, -1.0), "superior": (1, 1.0), "inferior": (1, -1.0)}


@dataclass(frozen=True)
class FrameFit:
    """The rigid map from the user's input (scaled to mm) to facesim's frame, and how it was found.

    T : (4, 4) float64, ``p_facesim = T[:3, :3] @ (scale_to_mm * p_input) + T[:3, 3]``, mm.
    scale_to_mm : factor from the input units to mm.
    units : name of the input units (``"m"``, ``"cm"``, ``"mm"``).
    symmetry_rms_mm : RMS distance (mm) of the mirrored surfaces to themselves (matched points).
    cues : tuple[str, ...], one line per cue used (symmetry, landmarks, spec).
    how : ``"anatomy"`` or ``"spec: ..."``.
    x_mid : the symmetry plane's x in facesim's frame (mm; ~0).
    occlusal_deg : tilt of the dental occlusal plane about the left axis, degrees (positive:
        rising toward the back), or None without both teeth.
    landmarks, landmark_how : the bone landmarks found in the final frame.
    """

    T: np.ndarray
    scale_to_mm: float = 1.0
    units: str = "mm"
    symmetry_rms_mm: float = float("nan")
    cues: tuple[str, ...] = ()
    how: str = "anatomy"
    x_mid: float = 0.0
    occlusal_deg: float | None = None
    landmarks: dict = field(default_factory=dict)
    landmark_how: dict = field(default_factory=dict)

    @property
    def R(self) -> np.ndarray:
        """(3, 3) rotation, input axes to facesim axes (rows: left, up, forward in input axes)."""
        return self.T[:3, :3]

    @property
    def inverse(self) -> np.ndarray:
        """(4, 4) facesim mm -> input frame in mm (divide by ``scale_to_mm`` for input units)."""
        Ti = np.eye(4)
        Ti[:3, :3] = self.R.T
        Ti[:3, 3] = -self.R.T @ self.T[:3, 3]
        return Ti

    def to_facesim(self, points) -> np.ndarray:
        """(k, 3) input points (input units) -> mm in facesim's frame."""
        return self.mm_to_facesim(self.scale_to_mm * np.asarray(points, dtype=np.float64))

    def mm_to_facesim(self, points_mm) -> np.ndarray:
        """(k, 3) input points already in mm -> facesim's frame."""
        return np.asarray(points_mm, dtype=np.float64) @ self.R.T + self.T[:3, 3]

    def to_input(self, points) -> np.ndarray:
        """(k, 3) facesim points (mm) -> the input frame, in input units."""
        P = (np.asarray(points, dtype=np.float64) - self.T[:3, 3]) @ self.R
        return P / self.scale_to_mm

    def axis(self, name: str) -> np.ndarray:
        """(3,) the input-frame unit vector of an anatomical direction (``"up"``, ``"forward"``...)."""
        row, sign = DIRECTIONS[name]
        return sign * self.R[row]

    def meta(self) -> dict:
        """JSON-serialisable description (for a model's meta or a landmarks file)."""
        return {"T_facesim_from_input_mm": np.round(self.T, 9).tolist(), "scale_to_mm": self.scale_to_mm,
                "units": self.units, "how": self.how, "symmetry_rms_mm": round(float(self.symmetry_rms_mm), 4),
                "occlusal_deg": None if self.occlusal_deg is None else round(float(self.occlusal_deg), 3),
                "cues": list(self.cues)}


def _transform(R: np.ndarray, origin: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = -R @ origin
    return T


# ============================================================================ symmetry
def _fibonacci_hemisphere(n: int) -> np.ndarray:
    k = np.arange(n) + 0.5
    z = k / n                                                # z in (0, 1): one of each +-n
    phi = np.pi * (1 + 5 ** 0.5) * k
    r = np.sqrt(1 - z * z)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def symmetry_plane(clouds: Sequence[np.ndarray], normals: Sequence[np.ndarray] | None = None, first: int = 0,
                   weights: Sequence[float] | None = None) -> tuple[np.ndarray, float, float]:
    """The plane ``{p: n . p = d}`` that best mirrors each point cloud of ``clouds`` (list of
    (k, 3) mm) onto itself: ``(n (3,) unit, d mm, rms mm)``.

    Candidates: the principal axes of ``clouds[first]`` (a symmetric body's mirror normal is one
    of them) and ``SYMMETRY_CANDIDATES`` directions over the sphere, each through that cloud's
    centroid, scored on it by the trimmed mean squared distance of its mirrored points to its
    nearest points. The best few are refined on all clouds: first "mirror, pair each point with
    the nearest point of its own cloud, fit the plane halfway between the pairs" with shrinking
    match distances, then Gauss-Newton on the point-to-plane distances of the mirrored points
    to the tangent planes of their matches (``normals``: (k, 3) per cloud, any sign; without
    them the first stage only), which converges to the smooth optimum rather than to wherever
    nearest-point matching stops. ``weights`` (default 1 each) scale each cloud's share of the
    points (taken evenly by distance from the centroid, so the same points wherever the cloud
    is moved). ``rms`` is the RMS distance of the matched mirrored points (within
    ``SYMMETRY_TRIM_MM``) after the fit.
    """
    weights = [1.0] * len(clouds) if weights is None else list(weights)
    trees = [cKDTree(c) for c in clouds]
    picks = [_even_subset_index(c, max(int(w * SYMMETRY_POINTS), 50)) for c, w in zip(clouds, weights)]
    queries = [c[i] for c, i in zip(clouds, picks)]
    base = queries[first]
    centre = clouds[first].mean(axis=0)

    def mirror(Q, n, d):
        return Q - 2.0 * (Q @ n - d)[:, None] * n

    def cost(n, d):
        total = 0.0
        for Q, tree in zip(queries, trees):
            total += float(np.mean(np.minimum(tree.query(mirror(Q, n, d))[0], SYMMETRY_TRIM_MM) ** 2))
        return total / len(queries)

    _, vecs = np.linalg.eigh(np.cov((base - centre).T))
    cands = np.concatenate([vecs.T, _fibonacci_hemisphere(SYMMETRY_CANDIDATES)])
    # the candidates scored on a subsample (fast), refined on the full clouds
    ctree, cq = cKDTree(_even_subset(clouds[first], 6000)), _even_subset(base, 300)
    scores = [float(np.mean(np.minimum(ctree.query(mirror(cq, n, n @ centre))[0], SYMMETRY_TRIM_MM) ** 2))
              for n in cands]
    best = None
    for k in np.argsort(scores)[:4]:
        n, d = cands[k], float(cands[k] @ centre)
        for trim in SYMMETRY_TRIMS:
            A, B = [], []
            for Q, tree, C in zip(queries, trees, clouds):
                dist, j = tree.query(mirror(Q, n, d))
                keep = dist < trim
                A.append(Q[keep])
                B.append(C[j[keep]])
            A, B = np.concatenate(A), np.concatenate(B)
            if len(A) < 10:
                break
            D = A - B
            _, v = np.linalg.eigh(D.T @ D)
            n_new = v[:, -1] * np.sign(v[:, -1] @ n or 1.0)
            d = float(np.mean((0.5 * (A + B)) @ n_new))
            n = n_new
        if normals is not None:
            n, d = _point_to_plane(queries, trees, normals, n, d)
        c = cost(n, d)
        if best is None or c < best[0]:
            best = (c, n, d)
    _, n, d = best
    dist = np.concatenate([(dd := tree.query(mirror(Q, n, d))[0])[dd < SYMMETRY_TRIM_MM]
                           for Q, tree in zip(queries, trees)])
    return n, d, float(np.sqrt(np.mean(dist ** 2))) if len(dist) else float("nan")


def _point_to_plane(queries, trees, normals, n, d, trim: float = 3.0, steps: int = 15):
    """Gauss-Newton on the distances of the mirrored ``queries`` to the tangent planes of their
    nearest points (``normals`` of the trees' points); parameters: two turns of ``n`` and ``d``."""
    for _ in range(steps):
        e1 = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(n, e1)
        J, r = [], []
        for Q, tree, N in zip(queries, trees, normals):
            s = Q @ n - d
            M = Q - 2.0 * s[:, None] * n
            dist, j = tree.query(M)
            keep = dist < trim
            Q, s, M, Nb = Q[keep], s[keep], M[keep], N[j[keep]]
            B = tree.data[j[keep]]
            r.append(np.einsum("ij,ij->i", Nb, M - B))
            cols = [-2.0 * ((Q @ e)[:, None] * n + s[:, None] * e) for e in (e1, e2)]
            J.append(np.stack([np.einsum("ij,ij->i", Nb, c) for c in cols] + [2.0 * Nb @ n], axis=1))
        J, r = np.concatenate(J), np.concatenate(r)
        if len(r) < 10:
            break
        step = np.linalg.lstsq(J, -r, rcond=None)[0]
        n = n + step[0] * e1 + step[1] * e2
        n /= np.linalg.norm(n)
        d = d + step[2]
        if np.abs(step[:2]).max() < 1e-7 and abs(step[2]) < 1e-5:
            break
    return n, float(d)


def _even_subset_index(P: np.ndarray, k: int) -> np.ndarray:
    """Indices of ``k`` points of ``P (n, 3)`` evenly spread over their distances from the
    centroid: the same points whatever the order of ``P`` and wherever it is moved (so a frame
    found from them is too)."""
    if len(P) <= k:
        return np.arange(len(P))
    r = np.linalg.norm(P - P.mean(axis=0), axis=1)
    order = np.argsort(np.round(r, 6), kind="stable")
    return order[np.linspace(0, len(P) - 1, k).astype(int)]


def _even_subset(P: np.ndarray, k: int) -> np.ndarray:
    """The points of :func:`_even_subset_index`."""
    return P[_even_subset_index(P, k)]


# ============================================================================ the frame
def _rotate_about_left(R: np.ndarray, theta: float) -> np.ndarray:
    """R followed by a rotation about facesim's x axis that adds ``theta`` (rad) to atan2(y, z)."""
    c, s = np.cos(theta), np.sin(theta)
    M = np.array([[1.0, 0.0, 0.0], [0.0, c, s], [0.0, -s, c]])
    return M @ R


def _sagittal_correction(landmarks: dict, how: dict) -> tuple[float, list[str]]:
    """The turn (rad) about the left axis that best matches the subject's condyle-to-landmark
    directions with the template's, and the names used."""
    origin = 0.5 * (landmarks["condyle_left"] + landmarks["condyle_right"])
    s = c = 0.0
    used = []
    for name in TEMPLATE_SAGITTAL:
        if name not in landmarks:
            continue
        on_bone = how.get(name) in (lm.HOW_INFRADENTALE, lm.HOW_PROSTHION)
        y_ref, z_ref = (TEMPLATE_SAGITTAL_BONE if on_bone else TEMPLATE_SAGITTAL)[name]
        p = landmarks[name] - origin
        delta = np.arctan2(y_ref, z_ref) - np.arctan2(p[1], p[2])
        w = SAGITTAL_WEIGHTS[name]
        s += w * np.sin(delta)
        c += w * np.cos(delta)
        used.append(name)
    return float(np.arctan2(s, c)), used


def _meshes(surfaces, scale, T, edges):
    out = []
    for srf, E in zip(surfaces, edges):
        if srf is None:
            out.append(None)
        else:
            V = (scale * srf.vertices) @ T[:3, :3].T + T[:3, 3]
            out.append(lm.Mesh(V, srf.faces, E))
    return out


def _occlusal_tilt(upper: lm.Mesh, lower: lm.Mesh) -> float | None:
    """Tilt (degrees) about facesim's x axis of the plane through the teeth's facing surfaces
    (points of each set within 3 mm of the closest approach to the other): positive when it
    rises toward the back."""
    tu, tl = cKDTree(upper.V), cKDTree(lower.V)
    du, _ = tl.query(upper.V)
    dl, _ = tu.query(lower.V)
    gap = min(du.min(), dl.min())
    P = np.concatenate([upper.V[du < gap + 3.0], lower.V[dl < gap + 3.0]])
    if len(P) < 10:
        return None
    _, v = np.linalg.eigh(np.cov((P - P.mean(axis=0)).T))
    n = v[:, 0] * np.sign(v[1, 0] or 1.0)                     # the normal, pointing up
    return float(np.degrees(np.arctan2(n[2], n[1])))


def parse_frame_spec(spec: str) -> np.ndarray:
    """(3, 3) rotation R (rows: facesim's left, up, forward as input-frame vectors) from a spec
    naming the anatomical direction of input axes, e.g. ``"x=-forward,y=left,z=up"`` or
    ``"x=backward, z=up"`` (two axes suffice: the third follows from right-handedness).
    A spec naming a direction twice, or describing a mirrored (left-handed) frame, is refused."""
    R = np.full((3, 3), np.nan)
    seen, columns = set(), set()
    parts = [p.strip() for p in str(spec).split(",") if p.strip()]
    if not parts:
        raise FacesimError(f"--frame: expected e.g. 'x=-forward,y=left,z=up', got {spec!r}")
    for part in parts:
        if "=" not in part:
            raise FacesimError(f"--frame: expected axis=direction (e.g. 'z=up'), got {part!r}")
        axis, direction = (t.strip().lower() for t in part.split("=", 1))
        if axis not in ("x", "y", "z"):
            raise FacesimError(f"--frame: axis must be x, y or z, got {axis!r}")
        sign = 1.0
        if direction.startswith(("-", "+")):
            sign, direction = (-1.0 if direction[0] == "-" else 1.0), direction[1:].strip()
        if direction not in DIRECTIONS:
            raise FacesimError(f"--frame: unknown direction {direction!r}; known: {', '.join(DIRECTIONS)}")
        row, dsign = DIRECTIONS[direction]
        col = "xyz".index(axis)
        if row in seen or col in columns:
            raise FacesimError(f"--frame: {spec!r} names an axis or a direction twice")
        seen.add(row)
        columns.add(col)
        R[row] = 0.0
        R[row, col] = sign * dsign
    if len(seen) < 2:
        raise FacesimError(f"--frame: name at least two axes, e.g. 'x=-forward,z=up'; got {spec!r}")
    if len(seen) == 2:
        missing = ({0, 1, 2} - seen).pop()
        a, b = [(missing + 1) % 3, (missing + 2) % 3]
        R[missing] = np.cross(R[a], R[b])
    if np.linalg.det(R) < 0.5:
        raise FacesimError(f"--frame: {spec!r} describes a mirrored (left-handed) frame; check the signs")
    return R


def anatomical_frame(mandible: Surface, cranium: Sequence[Surface] = (), skin: Surface | None = None,
                     teeth_upper: Surface | None = None, teeth_lower: Surface | None = None,
                     scale_to_mm: float = 1.0, units: str = "mm", spec: str | None = None) -> FrameFit:
    """The rigid transform from the input (after ``scale_to_mm``) to facesim's frame, found from
    the anatomy (see the module docstring) or, with ``spec``, from the user's axis spec
    (:func:`parse_frame_spec`) with the origin at the condyles' midpoint.

    Surfaces are in the input frame and units; ``cranium`` lists the cranium's parts (braincase,
    maxilla, ...; may be empty). Returns a :class:`FrameFit` with the bone landmarks found in the
    final frame.
    """
    surfaces = [mandible, *cranium, skin, teeth_upper, teeth_lower]
    samples = [sample_surface(s, spacing=SAMPLE_MM / scale_to_mm) for s in surfaces if s is not None]
    clouds = [scale_to_mm * p for p, _ in samples]
    M = clouds[0]
    edges = [None if s is None else lm.edges_of(s.faces) for s in surfaces]
    cues = []
    if spec is not None:
        R = parse_frame_spec(spec)
        how = f"spec: {spec}"
        cues.append(f"axes from --frame {spec!r}")
        n, d, rms = R[0], 0.0, float("nan")
        origin = M.mean(axis=0)
        iterations = 1
    else:
        # teeth (casts, scans) are the least symmetric: a quarter of the others' weight
        teeth = (id(teeth_upper), id(teeth_lower))
        weights = [TEETH_WEIGHT if id(s) in teeth else 1.0 for s in surfaces if s is not None]
        n, d, rms = symmetry_plane(clouds, normals=[q for _, q in samples], weights=weights)
        cues.append(f"symmetry plane of {len(clouds)} surfaces (mirror RMS {rms:.2f} mm)")
        R, origin = _first_guess(M, n, d)
        how = "anatomy"
        iterations = 12
    meshes = None

    def bones_at(R, origin):
        """The bone meshes in the frame (R, origin), the midline's x and the bone landmarks there."""
        man, *rest = _meshes(surfaces, scale_to_mm, _transform(R, origin), edges)
        cran = lm.Mesh.join(rest[:len(cranium)])
        tu, tl = rest[len(cranium) + 1], rest[len(cranium) + 2]
        x_mid = _plane_x(n, d, R, origin) if spec is None else 0.0
        return (tu, tl, x_mid, *lm.bone_landmarks(man, cran, tu, tl, x_mid=x_mid))

    for _ in range(iterations + 1):
        tu, tl, x_mid, found, found_how = bones_at(R, origin)
        mid = 0.5 * (found["condyle_left"] + found["condyle_right"])
        new_origin = origin + R.T @ mid
        theta, used = (0.0, []) if spec is not None else _sagittal_correction(found, found_how)
        moved = float(np.linalg.norm(new_origin - origin))
        origin = new_origin
        if spec is not None:
            continue
        R = _rotate_about_left(R, theta)
        if abs(theta) < np.deg2rad(0.01) and moved < 0.01:
            break
    T = _transform(R, origin)
    tu, tl, x_mid, found, found_how = bones_at(R, origin)
    if spec is None:
        cues.append(f"up and forward: directions from the condyles to {', '.join(used)} matched to the template's")
    occlusal = _occlusal_tilt(tu, tl) if tu is not None and tl is not None else None
    if occlusal is not None:
        cues.append(f"occlusal plane {occlusal:+.1f} deg to the horizontal (reported, not used)")
    return FrameFit(T=T, scale_to_mm=float(scale_to_mm), units=units, symmetry_rms_mm=rms, cues=tuple(cues), how=how,
                    x_mid=x_mid, occlusal_deg=occlusal, landmarks=found, landmark_how=found_how)


def _plane_x(n: np.ndarray, d: float, R: np.ndarray, origin: np.ndarray) -> float:
    """The symmetry plane's x in the frame ``(R, origin)`` (its normal is the frame's left axis)."""
    return float(np.sign(n @ R[0]) * (d - n @ origin))


def _first_guess(M: np.ndarray, n: np.ndarray, d: float) -> tuple[np.ndarray, np.ndarray]:
    """(R, origin) from the mandible's points ``M (k, 3)`` mm and its symmetry plane: see step 2
    of the module docstring."""
    c = M @ n - d
    mid = M[np.abs(c) < 4.0]
    if len(mid) < 10:
        mid = M[np.argsort(np.abs(c))[:max(10, len(M) // 50)]]
    chin = mid.mean(axis=0)
    cond = []
    for side in (1.0, -1.0):
        S = M[side * c > 0.5 * np.max(side * c)]
        cond.append(S[np.argmax(np.linalg.norm(S - chin, axis=1))])
    Cm = 0.5 * (cond[0] + cond[1])

    def flat(v):
        v = v - (v @ n) * n
        return v / np.linalg.norm(v)

    d0 = flat(chin - Cm)
    g = M.mean(axis=0) - Cm
    g = g - (g @ n) * n
    p = g - (g @ d0) * d0                        # toward the mandible's body: down
    up_perp = -p / np.linalg.norm(p)
    a = np.deg2rad(CHIN_ANGLE_DEG)
    forward = np.cos(a) * d0 + np.sin(a) * up_perp
    up = -np.sin(a) * d0 + np.cos(a) * up_perp
    left = np.cross(up, forward)
    return np.stack([left, up, forward]), Cm
