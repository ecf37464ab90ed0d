"""Procedural anatomical head: bones, teeth, eyes, mouth and skin as implicit fields.

The head is built the way forensic facial reconstruction works: first the skull (cranium with
the upper alveolar ridge, mandible with condyles, ramus, body and lower alveolar ridge), then
soft tissue laid over it with the tissue depths of ``docs/physics.md`` section 6
interpolated between landmarks, then the features bone does not carry (nose, lip rolls, neck).
The mouth is a fold of the skin: a thin slit between the lips opens into a vestibule around
the teeth crowns and into the oral cavity, all lined with flesh, so the skin is one closed
surface and the lips are free over the teeth.

Coordinates (mm): x toward the subject's left, y up, z toward the nose; origin between the
condyles. Everything is deterministic for given :class:`Subject` parameters; a seed gives a
reproducibly perturbed subject (:func:`subject_from_seed`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from facesim.anatomy import sdf
from facesim.model import JawGeometry


@dataclass(frozen=True)
class Subject:
    """Scalar proportions of one phantom subject (1.0 = the canonical head of docs/physics.md)."""

    width: float = 1.0          # lateral scale of the face skeleton
    height: float = 1.0         # vertical scale
    depth: float = 1.0          # antero-posterior scale
    jaw_length: float = 1.0     # scale of the mandible body and chin projection
    nose: float = 1.0           # nose size
    lips: float = 1.0           # lip fullness
    tissue: float = 1.0         # soft-tissue depth multiplier
    lip_gap: float = 2.4        # rest gap between the lips at the midline, mm

    def scaled(self, p) -> np.ndarray:
        """Scale a point ``(3,)`` or points ``(k, 3)`` given in canonical-head mm."""
        return np.asarray(p, float) * np.array([self.width, self.height, self.depth])


def subject_from_seed(seed: int) -> Subject:
    """Seed 0 is the canonical head; other seeds perturb proportions by a few percent."""
    if seed == 0:
        return Subject()
    rng = np.random.default_rng(seed)
    j = lambda s: float(1.0 + s * rng.standard_normal())  # noqa: E731
    return Subject(width=j(0.03), height=j(0.03), depth=j(0.025), jaw_length=j(0.03),
                   nose=j(0.06), lips=j(0.06), tissue=j(0.04), lip_gap=float(2.4 + 0.2 * rng.standard_normal()))


# --------------------------------------------------------------- canonical anatomy
#: Rest TMJ: condyle centres and the sliding track (down and forward along the eminence).
CONDYLE = np.array([50.0, 0.0, 0.0])
EMINENCE_SLOPE_DEG = 35.0
TRACK_LENGTH = 16.0
MAX_OPENING = 0.62
EYE_CENTRE = np.array([32.0, 27.0, 62.0])
EYE_RADIUS = 12.0


def _arch(half_width: float, front_z: float, depth: float, n: int = 17) -> tuple[np.ndarray, np.ndarray]:
    """Dental-arch centreline ``(n, 2)`` in (x, z), right molars to left molars, and its parameter s in [-1, 1]."""
    s = np.linspace(-1.0, 1.0, n)
    x = half_width * np.sin(s * np.pi / 2)
    z = front_z - depth * (1 - np.cos(s * np.pi / 2)) ** 0.85
    return np.stack([x, z], axis=1), s


@dataclass(frozen=True)
class DentalArches:
    """Centrelines, crown extents and alveolar ridges of both dental arches (mm)."""

    upper: np.ndarray        # (n, 2) centreline (x, z)
    lower: np.ndarray
    s: np.ndarray            # (n,) arch parameter
    upper_ht: np.ndarray     # (n,) crown half thickness
    lower_ht: np.ndarray
    upper_tip: np.ndarray    # (n,) incisal/occlusal y of upper crowns
    lower_tip: np.ndarray
    upper_neck: float        # y of the upper crown necks (gum line)
    lower_neck: float


def dental_arches(sub: Subject) -> DentalArches:
    W, D = sub.width, sub.depth
    up, s = _arch(24.5 * W, 78.5 * D, 42.0 * D)
    lo, _ = _arch(22.5 * W, 76.5 * D * sub.jaw_length ** 0.2, 39.0 * D)
    ht = 3.5 + 2.0 * np.abs(s) ** 1.5
    return DentalArches(
        upper=up, lower=lo, s=s, upper_ht=ht, lower_ht=ht - 0.3,
        upper_tip=(-38.0 + 2.5 * s ** 2) * sub.height,
        lower_tip=(-40.0 + 2.5 * s ** 2) * sub.height,
        upper_neck=-27.5 * sub.height, lower_neck=-48.5 * sub.height,
    )


def track_direction() -> np.ndarray:
    a = np.deg2rad(EMINENCE_SLOPE_DEG)
    return np.array([0.0, -np.sin(a), np.cos(a)])


def jaw_geometry(sub: Subject, arches: DentalArches) -> JawGeometry:
    """The subject's TMJ geometry: condyles, sliding tracks, maximum opening, lower incisal point."""
    mid = len(arches.s) // 2
    return JawGeometry(
        condyle_right=sub.scaled(CONDYLE * np.array([-1.0, 1.0, 1.0])),
        condyle_left=sub.scaled(CONDYLE),
        track_direction=track_direction(),
        track_length=TRACK_LENGTH,
        max_opening=MAX_OPENING,
        incisor=np.array([0.0, arches.lower_tip[mid], arches.lower[mid, 1] + arches.lower_ht[mid]]),
    )


def jaw_range_poses(geometry: JawGeometry, n_opening: int = 25, n_slide: int = 5) -> np.ndarray:
    """``(k, 4, 4)`` mandible poses (relative to the cranium) covering the sliding-condyle jaw's
    whole range: every opening in ``[0, max_opening]`` with every pair of condyle slides in
    ``[0, track_length]`` on a regular grid (``n_opening`` x ``n_slide`` x ``n_slide`` poses).
    Between neighbouring poses no mandible point moves more than ~3 mm (coarse model)."""
    from facesim.kinematics.condyle import SlidingCondyleJaw

    jaw = SlidingCondyleJaw(geometry)
    slides = np.linspace(0.0, geometry.track_length, n_slide)
    return np.array([jaw.transform([t, r, l]) for t in np.linspace(0.0, geometry.max_opening, n_opening)
                     for r in slides for l in slides])


def swept_occupancy(g: sdf.Grid, inside: np.ndarray, poses: np.ndarray, stride: int = 2) -> np.ndarray:
    """Voxels of ``g`` a rigid body occupying ``inside`` (grid shape, bool) covers in any of the
    ``poses (k, 4, 4)``.

    Worked on blocks of ``stride``³ voxels (a block is occupied if any of its voxels is): each
    occupied block centre is moved by every pose and rounded to the nearest block. A distance
    measured from the result is off by up to about the block diagonal plus half the distance a
    point moves from one pose to the next (a few mm for :func:`jaw_range_poses`), fine for
    clearances of centimetres.
    """
    n = np.array(g.shape)
    m = -(-n // stride)
    pad = np.zeros(m * stride, bool)
    pad[:n[0], :n[1], :n[2]] = inside
    blocks = pad.reshape(m[0], stride, m[1], stride, m[2], stride).any(axis=(1, 3, 5))
    hb = g.h * stride
    origin = np.asarray(g.lo) + 0.5 * (stride - 1) * g.h       # centre of block (0, 0, 0)
    P = origin + hb * np.argwhere(blocks)
    out = np.zeros(blocks.size, bool)
    for T in poses:
        ijk = np.rint((P @ T[:3, :3].T + (T[:3, 3] - origin)) / hb).astype(np.int64)
        ok = np.all((ijk >= 0) & (ijk < m), axis=1)
        out[np.ravel_multi_index(tuple(ijk[ok].T), tuple(m))] = True
    out = out.reshape(m)
    for axis in range(3):
        out = np.repeat(out, stride, axis=axis)
    return out[:n[0], :n[1], :n[2]]


# --------------------------------------------------------------- the fields
@dataclass
class HeadFields:
    """Signed distance fields (mm, negative inside) of every part, sampled on ``grid``."""

    grid: sdf.Grid
    cranium: np.ndarray
    jaw: np.ndarray
    eyes: np.ndarray
    teeth_upper: np.ndarray
    teeth_lower: np.ndarray
    mouth: np.ndarray        # the oral void (slit, vestibule, cavity), lined with flesh
    joint: np.ndarray        # void around the TMJ sliding tracks
    skin: np.ndarray         # outer skin (mouth not carved)
    cranium_skull: np.ndarray  # the skull alone, before the rigid core is grown (rendering, depths)

    crop: np.ndarray = None  # the flat cut through the neck (negative above it)

    @property
    def flesh(self) -> np.ndarray:
        """Flesh region: inside the skin and above the neck cut, outside bone, eyes, mouth and joint voids."""
        f = np.maximum(self.skin, -self.cranium)
        if self.crop is not None:
            np.maximum(f, self.crop, out=f)
        np.maximum(f, -self.jaw, out=f)
        np.maximum(f, -self.eyes, out=f)
        np.maximum(f, -self.mouth, out=f)
        np.maximum(f, -self.joint, out=f)
        return f


def mirror_pair(fn, x, y, z, p, *args):
    """Union of a primitive placed at ``p`` and at its mirror image (x -> -x)."""
    p = np.asarray(p, float)
    q = p * np.array([-1.0, 1.0, 1.0])
    return np.minimum(fn(x, y, z, p, *args), fn(x, y, z, q, *args))


def mirror_chain(x, y, z, points, radii):
    pts = np.asarray(points, float)
    return np.minimum(sdf.capsule_chain(x, y, z, pts, radii),
                      sdf.capsule_chain(x, y, z, pts * np.array([-1.0, 1.0, 1.0]), radii))


def _polygon_sdf_2d(u, v, poly):
    """Signed distance (negative inside) of points (u, v) to a closed polygon ``(k, 2)``."""
    poly = np.asarray(poly, float)
    d2 = None
    inside = np.zeros(np.broadcast(u, v).shape, dtype=bool)
    for i in range(len(poly)):
        a, b = poly[i], poly[(i + 1) % len(poly)]
        ab = b - a
        t = np.clip(((u - a[0]) * ab[0] + (v - a[1]) * ab[1]) / (ab @ ab), 0, 1)
        dd = (u - a[0] - t * ab[0]) ** 2 + (v - a[1] - t * ab[1]) ** 2
        d2 = dd if d2 is None else np.minimum(d2, dd)
        cond = (a[1] > v) != (b[1] > v)
        xint = a[0] + (v - a[1]) * ab[0] / np.where(ab[1] == 0, 1e-12, ab[1])
        inside ^= cond & (u < xint)
    d = np.sqrt(d2)
    return np.where(inside, -d, d).astype(np.float32)


def cranium_field(g: sdf.Grid, sub: Subject, arches: DentalArches) -> np.ndarray:
    x, y, z = g.axes()
    S = sub.scaled
    # neurocranium: a boxy superellipsoid, its base tilted up toward the orbits
    d = sdf.superellipsoid(x, y, z, S([0, 50, -14]), S([70, 84, 95]), 2.5)
    base = sdf.halfspace(x, y, z, S([0, 10, 0]), [0.0, -1.0, 0.42])
    d = sdf.smooth_intersect(d, base, 6.0)
    # skull base and cervical column (rigid core the neck flesh hangs on); the pharynx in front
    # of the column is soft: the tongue base moves back into it when the mouth opens
    core = sdf.box(x, y, z, S([0, -10, -20]), S([27, 30, 26]), rounding=10.0)
    core = np.minimum(core, sdf.capsule_chain(x, y, z, S([[0, -20, -36], [0, -60, -39], [0, -88, -40]]), 17.0))
    d = sdf.smooth_union(d, core, 8.0)
    # mastoids behind the ear canals, ~20 mm behind the ramus: the posterior border swings back
    # toward them when the mouth opens and the parotid tissue between must not be pinched
    d = sdf.smooth_union(d, mirror_pair(sdf.ellipsoid, x, y, z, S([53, -12, -35]), S([9, 14, 9])), 5.0)
    # brow ridges and nasal bridge
    d = sdf.smooth_union(d, mirror_chain(x, y, z, S([[6, 45, 81], [22, 47, 79], [38, 44, 72], [47, 36, 61]]), 4.0), 6.0)
    d = sdf.smooth_union(d, sdf.ellipsoid(x, y, z, S([0, 27, 64]), S([17, 17, 20])), 5.0)
    d = sdf.smooth_union(d, sdf.capsule_chain(x, y, z, S([[0, 40, 77], [0, 29, 84], [0, 17, 90]]), [6.0, 5.0, 4.0]), 5.0)
    # maxilla and upper alveolar ridge
    d = sdf.smooth_union(d, sdf.superellipsoid(x, y, z, S([0, -4, 52]), S([37, 23, 31]), 2.6), 6.0)
    d = sdf.smooth_union(d, sdf.arch_sweep(x, y, z, arches.upper, arches.upper_ht + 1.5,
                                           arches.upper_neck + 4.0, -8.0 * sub.height, 2.0), 4.0)
    # zygomatic bodies and arches
    d = sdf.smooth_union(d, mirror_pair(sdf.ellipsoid, x, y, z, S([45, 9, 58]), S([11, 10, 11])), 6.0)
    d = sdf.smooth_union(d, mirror_chain(x, y, z, S([[50, 7, 55], [59, 5, 38], [61, 5, 24], [60, 6, 6], [57, 7, -10]]), 3.5), 4.0)
    # orbits: eyeball sockets and the opening in front of them
    d = np.maximum(d, -mirror_pair(sdf.sphere, x, y, z, S(EYE_CENTRE), EYE_RADIUS + EYE_GAP))
    d = sdf.smooth_subtract(d, mirror_pair(sdf.ellipsoid, x, y, z, S(EYE_CENTRE + [1, 0, 12]), [17, 15, 11]), 2.5)
    # the articular fossa must leave room for the condyle sliding down its track
    d = np.maximum(d, -joint_field_raw(x, y, z, sub))
    return d.astype(np.float32)


#: Radius of the joint void around each condyle's sliding track (mm): the condyle (18 mm
#: across) keeps ~3.5 mm of it all round, so no flesh element reaches from the condyle to the
#: fossa or the root of the zygomatic arch.
JOINT_RADIUS = 12.5


def joint_field_raw(x, y, z, sub: Subject, margin: float = 0.0):
    c = sub.scaled(CONDYLE)
    v = track_direction()
    pts = lambda c: np.array([c, c + TRACK_LENGTH * v])  # noqa: E731
    mirror = c * np.array([-1.0, 1.0, 1.0])
    r = JOINT_RADIUS + margin
    return np.minimum(sdf.capsule_chain(x, y, z, pts(c), r), sdf.capsule_chain(x, y, z, pts(mirror), r))


def mandibular_arch(sub: Subject) -> np.ndarray:
    """``(11, 2)`` centreline (x, z) of the body of the mandible, right angle to left angle, mm."""
    c = np.array([[-44, -2], [-42, 18], [-37.5, 38], [-28, 56], [-15, 68.5], [0, 72.5]], float)
    return np.vstack([c, c[-2::-1] * [-1, 1]]) * np.array([sub.width, sub.depth * sub.jaw_length])


def floor_of_mouth_field(g: sdf.Grid, sub: Subject, arches: DentalArches) -> np.ndarray:
    """The space the mandibular arch encloses, from below its lower border up to the crown necks:
    floor of the mouth, tongue base and suprahyoid muscles, all carried by the mandible when
    the mouth opens (used to keep the rigid core out of their way, not as a part of the head)."""
    x, y, z = g.axes()
    zz, xx = np.broadcast_arrays(z[0, 0][None, :], x[:, 0, 0][:, None])
    inside = _polygon_sdf_2d(xx, zz, mandibular_arch(sub))[:, None, :]
    band = np.abs(y - 0.5 * (arches.lower_neck - 86.0 * sub.height)) - 0.5 * (arches.lower_neck + 86.0 * sub.height)
    return np.maximum(inside, band).astype(np.float32)


def jaw_field(g: sdf.Grid, sub: Subject, arches: DentalArches) -> np.ndarray:
    x, y, z = g.axes()
    S = sub.scaled
    J = sub.jaw_length
    d = mirror_pair(sdf.ellipsoid, x, y, z, S(CONDYLE), [9.0, 5.0, 5.5])
    # ramus: a plate in the (z, y) plane at |x| ~ 47.5 with condylar neck, notch and coronoid; the
    # coronoid tip stays ~10 mm under the zygomatic arch (the temporalis tendon passes between)
    poly = np.array([[-4, -4], [4, -5], [11, -14], [21, -10], [25, -14], [31, -40], [36, -52],
                     [8, -64], [-5, -57], [-7, -30]], float) * np.array([sub.depth, sub.height])
    zz, yy = np.broadcast_arrays(z[0], y[0])
    p2 = _polygon_sdf_2d(zz, yy, poly)[None, :, :] - 1.5
    plate = np.maximum(p2, np.abs(np.abs(x) - 47.5 * sub.width) - 4.0)
    d = sdf.smooth_union(d, plate, 3.0)
    d = sdf.smooth_union(d, mirror_chain(x, y, z, S([[50, -1, 0], [49, -8, -2]]), 4.5), 3.0)
    # body along the mandibular arch, from the angle to the symphysis
    c = mandibular_arch(sub)
    k = len(c)
    t = np.abs(np.linspace(-1, 1, k))
    ht = 5.0 + 1.8 * (1 - t)
    ylo = (-86.0 + 24.0 * t ** 1.6) * sub.height
    yhi = np.full(k, arches.lower_neck - 4.0)
    yhi[t > 0.8] = np.interp(t[t > 0.8], [0.8, 1.0], [arches.lower_neck - 4.0, -42.0 * sub.height])
    d = sdf.smooth_union(d, sdf.arch_sweep(x, y, z, c, ht, ylo, yhi, 3.0), 5.0)
    # lower alveolar ridge under the lower crowns and the chin boss
    d = sdf.smooth_union(d, sdf.arch_sweep(x, y, z, arches.lower, arches.lower_ht + 1.5, -66.0 * sub.height,
                                           arches.lower_neck - 4.0, 2.0), 4.0)
    # behind the last molars the ridge runs back and out into the body (the lingual retromolar
    # ridge): no back-facing step for the floor of the mouth to catch on when the jaw swings back
    for side in (-1.0, 1.0):
        end = arches.lower[0 if side < 0 else -1]
        ramp = np.array([end, [side * 35.0 * sub.width, 12.0 * sub.depth]])
        d = sdf.smooth_union(d, sdf.arch_sweep(x, y, z, ramp, [arches.lower_ht[0] + 1.5, 3.0],
                                               [-66.0 * sub.height, -66.0 * sub.height],
                                               [arches.lower_neck - 4.0, arches.lower_neck - 5.5], 2.0), 4.0)
    d = sdf.smooth_union(d, sdf.ellipsoid(x, y, z, S([0, -76, 73 * J]), [16, 10, 6.5]), 5.0)
    return d.astype(np.float32)


def teeth_fields(g: sdf.Grid, sub: Subject, arches: DentalArches) -> tuple[np.ndarray, np.ndarray]:
    x, y, z = g.axes()
    up = sdf.arch_sweep(x, y, z, arches.upper, arches.upper_ht, arches.upper_tip, arches.upper_neck, 1.5)
    lo = sdf.arch_sweep(x, y, z, arches.lower, arches.lower_ht, arches.lower_neck, arches.lower_tip, 1.5)
    return up.astype(np.float32), lo.astype(np.float32)


#: Gap between an eyeball and the lids / socket around it, mm.
EYE_GAP = 0.8


def eyes_field(g: sdf.Grid, sub: Subject) -> np.ndarray:
    """Eye void: the eyeball plus a thin gap, so lids slide over it and the socket holds it."""
    x, y, z = g.axes()
    return mirror_pair(sdf.sphere, x, y, z, sub.scaled(EYE_CENTRE), EYE_RADIUS + EYE_GAP).astype(np.float32)


def mouth_corner_x(sub: Subject) -> float:
    return 26.0 * sub.width


def stomion_y(sub: Subject) -> float:
    return -39.2 * sub.height


def mouth_field(g: sdf.Grid, sub: Subject, arches: DentalArches, teeth_up, teeth_lo, bone_exact) -> np.ndarray:
    """Oral void: 1.5 mm around the crowns, the slit between the lips, the oral cavity proper.

    Kept 2.5 mm away from bone so the mucosa lines it and the skin stays one closed surface.
    """
    x, y, z = g.axes()
    S = sub.scaled
    crowns = np.minimum(teeth_up, teeth_lo)
    v = crowns - 1.5
    # oral cavity proper inside the arches (tongue space), and the space between the crowns
    cav = sdf.superellipsoid(x, y, z, S([0, -40, 50]), S([20, 9, 24]), 2.5)
    v = np.minimum(v, cav)
    # slit between the lips: half gap tapering to zero at the corners, from the crowns out through the skin
    xc = mouth_corner_x(sub)
    half = 0.5 * sub.lip_gap * np.sqrt(np.clip(1.0 - (x / xc) ** 2, 0.0, 1.0))
    ys = stomion_y(sub) + 0.004 * x ** 2
    slit = np.maximum(np.abs(y - ys) - half, np.abs(x) - xc)
    slit = np.maximum(slit, -(z - 60.0 * sub.depth))
    v = np.minimum(v, slit)
    return np.maximum(v, 2.5 - bone_exact).astype(np.float32)


#: Soft-tissue depth landmarks: name, bone point (canonical mm), outward direction, target depth (mm),
#: accepted range (docs/physics.md section 6; None where the table gives none).
DEPTH_LANDMARKS = [
    ("glabella", (0, 48, 82), (0, 0.15, 1), 2.8, (5.0, 6.0)),
    ("nasion", (0, 38, 80), (0, 0, 1), 5.6, (6.5, 7.0)),
    ("mid_philtrum", (0, -18, 84), (0, 0, 1), 11.0, (10.0, 12.0)),
    ("labrale_superius", (0, -33, 82), (0, 0, 1), 12.0, (11.0, 13.0)),
    ("labrale_inferius", (0, -46, 80), (0, 0, 1), 8.8, (11.0, 13.0)),
    ("pogonion", (0, -76, 80), (0, 0, 1), 10.5, (10.0, 11.0)),
    ("malar_L", (50, 10, 62), (0.6, 0, 0.8), 16.5, (13.0, 16.0)),
    ("malar_R", (-50, 10, 62), (-0.6, 0, 0.8), 16.5, (13.0, 16.0)),
    ("cheek_molar_L", (29, -32, 45), (1, 0, 0), 13.0, (19.0, 24.0)),
    ("cheek_molar_R", (-29, -32, 45), (-1, 0, 0), 13.0, (19.0, 24.0)),
    ("gonion_L", (47, -58, -5), (0.8, -0.5, -0.3), 15.0, (14.0, 16.0)),
    ("gonion_R", (-47, -58, -5), (-0.8, -0.5, -0.3), 15.0, (14.0, 16.0)),
]

#: Local skin offsets (mm, + outward) at landmarks, Gaussian of DEPTH_CORRECTION_SIGMA mm.
DEPTH_CORRECTIONS = {"glabella": -1.3, "nasion": 0.75, "labrale_inferius": -1.1, "pogonion": 0.6}
DEPTH_CORRECTION_SIGMA = 6.0

#: Extra depth controls that shape the rest of the head (no published range checked).
DEPTH_CONTROLS = [
    ((0, 80, 72), (0, 0.3, 1), 5.0), ((32, 72, 62), (0.5, 0.3, 1), 5.0), ((-32, 72, 62), (-0.5, 0.3, 1), 5.0),
    ((0, 134, -12), (0, 1, 0), 6.0), ((0, 50, -110), (0, 0, -1), 7.0), ((70, 50, -15), (1, 0, 0), 6.0),
    ((-70, 50, -15), (-1, 0, 0), 6.0), ((66, 30, 20), (1, 0, 0), 8.0), ((-66, 30, 20), (-1, 0, 0), 8.0),
    ((30, 44, 76), (0, 0.3, 1), 7.0), ((-30, 44, 76), (0, 0.3, 1), 7.0),
    ((32, 27, 74), (0, 0, 1), 3.5), ((-32, 27, 74), (0, 0, 1), 3.5),
    ((33, 12, 70), (0, -0.2, 1), 9.0), ((-33, 12, 70), (0, -0.2, 1), 9.0),
    ((62, 5, 25), (1, 0, 0), 7.0), ((-62, 5, 25), (-1, 0, 0), 7.0),
    ((0, -60, 77), (0, 0, 1), 10.5), ((0, -88, 68), (0, -1, 0.3), 7.5),
    ((45, -64, 30), (1, -0.3, 0), 12.0), ((-45, -64, 30), (-1, -0.3, 0), 12.0),
    ((60, -30, 10), (1, 0, 0), 6.0), ((-60, -30, 10), (-1, 0, 0), 6.0),
    ((38, -22, 62), (0.7, 0, 0.7), 17.0), ((-38, -22, 62), (-0.7, 0, 0.7), 17.0),
    ((25, -52, 68), (0.5, 0, 0.9), 12.0), ((-25, -52, 68), (-0.5, 0, 0.9), 12.0),
]


def depth_field(g: sdf.Grid, sub: Subject) -> np.ndarray:
    """Soft-tissue depth (mm) everywhere: Gaussian-weighted blend of the landmark depths.

    Each landmark's weight is centred half way out along its direction, where the skin it
    controls will be, so the blend is evaluated where the skin lies.
    """
    x, y, z = g.axes()
    num = np.zeros(g.shape, np.float32)
    den = np.zeros(g.shape, np.float32)
    entries = [(p, n, d) for _, p, n, d, _ in DEPTH_LANDMARKS] + DEPTH_CONTROLS
    sigma = 16.0
    for p, n, dep in entries:
        n = np.asarray(n, float) / np.linalg.norm(n)
        c = sub.scaled(p) + 0.5 * dep * n
        w = np.exp(-((x - c[0]) ** 2 + (y - c[1]) ** 2 + (z - c[2]) ** 2) / np.float32(2 * sigma ** 2))
        num += w * np.float32(dep * sub.tissue)
        den += w
    base = np.float32(1e-6)  # far from every landmark the depth falls back to 6.5 mm
    return (num + base * 6.5 * sub.tissue) / (den + base)


def skin_field(g: sdf.Grid, sub: Subject, bone_and_eyes_exact: np.ndarray) -> np.ndarray:
    x, y, z = g.axes()
    S = sub.scaled
    d = bone_and_eyes_exact - depth_field(g, sub)
    # nose: dorsum, tip and alae on top of the nasal bones
    N = sub.nose
    nose = sdf.capsule_chain(x, y, z, S([[0, 34, 85], [0, 12, 99], [0, -1, 106 + 6 * (N - 1)]]),
                             [4.5, 6.0 * N, 8.0 * N])
    nose = sdf.smooth_union(nose, mirror_pair(sdf.ellipsoid, x, y, z, S([13.5, -8, 96]), [7 * N, 6 * N, 7.5 * N]), 5)
    nose = sdf.smooth_union(nose, sdf.ellipsoid(x, y, z, S([0, -10, 101]), [7 * N, 4.5, 8 * N]), 4)
    d = sdf.smooth_union(d, nose, 6.0)
    # lip rolls (vermilion) along the lip line
    L = sub.lips
    xs = np.linspace(-1, 1, 9)
    upper = np.stack([24 * xs, -36.0 + 2.5 * xs ** 2 - 1.0 * (1 - xs ** 2), 93.5 - 8 * xs ** 2], 1)
    lower = np.stack([22 * xs, -43.5 - 0.5 * (1 - xs ** 2) + 3.0 * xs ** 2, 92.0 - 8 * xs ** 2], 1)
    d = sdf.smooth_union(d, sdf.capsule_chain(x, y, z, S(upper), 3.2 * L * np.sqrt(1 - 0.6 * xs ** 2)), 4.0)
    d = sdf.smooth_union(d, sdf.capsule_chain(x, y, z, S(lower), 2.7 * L * np.sqrt(1 - 0.6 * xs ** 2)), 4.0)
    # neck stub, cut flat
    neck = sdf.capsule_chain(x, y, z, S([[0, -40, -25], [0, -175, -41]]), 54.0)
    neck = np.maximum(neck, sdf.halfspace(x, y, z, S([0, 20, 0]), [0, 1, 0]))
    d = sdf.smooth_union(d, neck, 14.0)
    # the neck runs on below the cut (NECK_CUT_Y) so the cut meets it at a clean right angle
    d = sdf.smooth_intersect(d, sdf.halfspace(x, y, z, S([0, NECK_CUT_Y - 6.0, 0]), [0, -1, 0]), 3.0)
    # local corrections where the blend, the closed bone support and the nose and lip shapes
    # leave a landmark's depth outside its published range (tuned by measuring the field)
    for name, p, n, dep, _ in DEPTH_LANDMARKS:
        corr = DEPTH_CORRECTIONS.get(name, 0.0)
        if corr:
            n = np.asarray(n, float) / np.linalg.norm(n)
            c = S(p) + dep * sub.tissue * n
            r2 = (x - c[0]) ** 2 + (y - c[1]) ** 2 + (z - c[2]) ** 2
            d = d - np.float32(corr * sub.tissue) * np.exp(-r2 / np.float32(2 * DEPTH_CORRECTION_SIGMA ** 2))
    d = ndimage.gaussian_filter(d, 1.5 / g.h)
    return d.astype(np.float32)


def soft_masses(g: sdf.Grid, sub: Subject) -> np.ndarray:
    """Bulk soft tissue the skin drapes over but the model does not simulate as bone: masseter,
    parotid, and under the floor of the mouth the suprahyoid muscles and submandibular glands,
    which fill the arch down to about its lower border (a submental skin drawn up into the
    arch buckles into a crease when the open jaw swings the chin back toward the throat)."""
    x, y, z = g.axes()
    S = sub.scaled
    m = mirror_chain(x, y, z, S([[54, 0, 18], [52, -30, 12], [49, -56, 2]]), [5.0, 5.0, 4.0])
    m = sdf.smooth_union(m, mirror_pair(sdf.ellipsoid, x, y, z, S([58, -20, -12]), [8, 16, 10]), 6.0)
    return np.minimum(m, sdf.ellipsoid(x, y, z, S([0, -78, 38]), S([26, 9, 24])))


#: Flesh deeper than this under the skin is part of the rigid cranium body (mm) ...
CORE_DEPTH = 14.0
#: Height of the flat cut through the neck stub (canonical mm): ~60 mm below the menton, which
#: the open jaw brings down to ~35 mm above it.
NECK_CUT_Y = -150.0
#: ... unless it is within these distances of the mandible (in any pose of its range), the mouth,
#: the eyes or the joints (mm).
CORE_CLEARANCE = {"jaw": 20.0, "mouth": 8.0, "eyes": 4.0, "joint": 5.0}


def deep_core(g: sdf.Grid, cranium, jaw, eyes, mouth, joint, skin, cut_y: float, jaw_poses=None) -> np.ndarray:
    """Cranium field grown into the deep interior of the head (pharynx, skull base, neck core).

    The simulated flesh is the layer under the skin, as in Sifakis et al. 2005: deeper tissue
    that facial expressions barely move is treated as part of the rigid cranium body. ``jaw`` is
    the field of the mandible and what it carries (the floor of the mouth inside its arch); the
    core keeps ``CORE_CLEARANCE["jaw"]`` from it in every pose of ``jaw_poses (k, 4, 4)``
    (default: the rest pose only), not only at rest: opening swings the angles back by ~20 mm
    and the body of the mandible down and back by ~30 mm, and flesh caught between the moving
    bone and a rigid core there (floor of the mouth, medial to the ramus and the angle) has
    nowhere to go and inverts. So that tissue is free flesh: the mandible carries it back
    toward the cervical column, and the neck in front of the column gives way.
    """
    deep = sdf.exact_sdf(skin < 0, g.h) < -CORE_DEPTH
    # the core stops short of the neck cut, so the cut is a solid disc of flesh and the skin
    # with that disc closes the head
    deep &= np.broadcast_to(g.axes()[1] > cut_y + CORE_DEPTH, g.shape)
    poses = np.eye(4)[None] if jaw_poses is None else np.asarray(jaw_poses, float)
    swept = swept_occupancy(g, jaw < 0, poses)
    for name, inside in (("jaw", swept), ("mouth", mouth < 0), ("eyes", eyes < 0), ("joint", joint < 0)):
        deep &= sdf.exact_sdf(inside, g.h) > CORE_CLEARANCE[name]
    occ = (cranium < 0) | deep
    grown = ndimage.gaussian_filter(sdf.exact_sdf(occ, g.h), 0.8 / g.h)
    # keep the analytic field where no core was added (sharper features)
    return np.where(deep | (grown < cranium), np.minimum(grown, cranium), cranium).astype(np.float32)


#: The simulated face region in canonical mm: behind the mandibular angles by more than they
#: swing back at full opening (~25 mm), so the soft tissue around the ramus can follow the
#: mandible; the whole neck stub (at full opening the chin drops ~35 mm and swings ~50 mm back,
#: toward the throat); below the upper forehead. The rest of the head (scalp, back of the head)
#: is meshed but not simulated: its nodes move with the cranium.
FACE_REGION = {"z_min": -55.0, "y_min": -200.0, "y_max": 100.0}


def neck_cut(g: sdf.Grid, sub: Subject) -> np.ndarray:
    """Signed distance to the flat cut through the neck stub (negative above it)."""
    y = g.axes()[1]
    return np.broadcast_to(float(NECK_CUT_Y * sub.height) - y, g.shape).astype(np.float32)


def build_fields(sub: Subject, h: float = 1.0, progress=None) -> HeadFields:
    """Evaluate every part on a grid of spacing ``h`` mm covering the head."""
    lo = sub.scaled([-92, -160, -125])
    hi = sub.scaled([92, 145, 135])
    g = sdf.Grid.around(lo, hi, h)
    step = (lambda msg: progress(msg)) if progress else (lambda msg: None)
    arches = dental_arches(sub)
    step("cranium")
    cranium = cranium_field(g, sub, arches)
    step("mandible")
    jaw = jaw_field(g, sub, arches)
    step("teeth, eyes, joints")
    t_up, t_lo = teeth_fields(g, sub, arches)
    eyes = eyes_field(g, sub)
    x, y, z = g.axes()
    joint = joint_field_raw(x, y, z, sub).astype(np.float32)
    step("exact distances")
    bone_exact = sdf.exact_sdf((cranium < 0) | (jaw < 0), h)
    # skin lies over the skull as the soft-tissue depth over its closing: fossae are filled by muscle
    support = (cranium < 0) | (jaw < 0) | (eyes < 0) | (t_up < 0) | (t_lo < 0) | (soft_masses(g, sub) < 0)
    support = sdf.closing(support, 24.0, h)
    bone_eyes_exact = sdf.exact_sdf(support, h)
    step("mouth")
    mouth = mouth_field(g, sub, arches, t_up, t_lo, bone_exact)
    step("skin")
    skin = skin_field(g, sub, bone_eyes_exact)
    step("rigid core")
    skull = cranium
    carried = np.minimum(jaw, floor_of_mouth_field(g, sub, arches))
    cranium = deep_core(g, cranium, carried, eyes, mouth, joint, skin, NECK_CUT_Y * sub.height,
                        jaw_poses=jaw_range_poses(jaw_geometry(sub, arches)))
    crop = neck_cut(g, sub)
    return HeadFields(grid=g, cranium=cranium, cranium_skull=skull, crop=crop, jaw=jaw, eyes=eyes, teeth_upper=t_up, teeth_lower=t_lo,
                      mouth=mouth, joint=joint, skin=skin)

