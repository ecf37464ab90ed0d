"""Synthetic jaw motion from temporomandibular-joint anatomy: capture-like sessions for the rigs.

The mandible is placed by its two condyles, each sliding along a curved path over its articular
eminence, and by a rotation about the intercondylar axis (docs/physics.md section 3 for the ranges).

Eminence path. In the sagittal plane spanned by the chord direction v (the model's
``track_direction``, forward and down) and n = v × u (u: unit right -> left condyle), the
condyle at arc length s sits at c0 + a(s) v + b(s) n, its tangent turned by
psi(s) = delta (1 − 2 s / L) below the chord: steeper than v on the posterior slope, flatter near
the crest (delta = ``eminence_curvature``, L = ``condyle_translation``)::

    a(s) = L / (2 delta) [sin delta − sin psi(s)],   b(s) = L / (2 delta) [cos delta − cos psi(s)]

Pose from the condyle slides. With slides s_R, s_L, side shift b (Bennett), distraction e and
opening angle theta, the condyles go to C_R = c_R + path(s_R) + b u − e n and C_L likewise; the
mandible is rotated by theta about u, then by the smallest rotation taking u to the unit
C_L − C_R (the yaw and roll of a lateral excursion), and moved so that the condyle midpoint
lands on (C_R + C_L) / 2. A pose is therefore rigid by construction.

Controls. A session is a path of ``latent = (o, p, l)`` -- opening in [0, 1], protrusion in
[0, 1], laterality in [−1, 1] (positive: the chin to the subject's left) -- plus the opening
direction h = tanh(do/dt / 0.3 s⁻¹) in [−1, 1]. They set::

    theta  = theta_c (1 − o) + theta_max o,        theta_c = theta_p p + theta_l (l+ + l−)
    r      = clip((theta − theta_h) / (theta_max − theta_h), 0, 1)
    s_open = S_o r² (2 − r) + eta h 27/4 r² (1 − r)
    s_mid  = s_open + p softplus(S_p − s_open)
    s_R    = s_mid + S_l (1 − s_mid / S_top)² l+ − kappa s_mid l−     (s_L: l+ and l− swapped)
    b      = beta (l+ − l−),                       e = D (1 + h) / 2 sin(pi o)

with l+ and l− C¹ positive parts of l and −l. Pure rotation about the condyles up to theta_h
(the hinge opening), then translation reaching S_o at the maximum opening; protrusion moves both
condyles forward in tooth contact, theta_p keeping the incisor on the incisal guidance; in a
lateral excursion to the left the right (balancing) condyle travels down its eminence while the
left (working) condyle stays, giving back a fraction kappa of its slide, and the mandible shifts
toward the working side. The condyles lead on opening and lag on closing (hysteresis eta) and,
while opening, ride up to D mm below their closing path (joint play), which takes the poses off
the 3-D manifold of the controls, as in real capture. theta_h, theta_max, S_p, theta_p, S_l and
theta_l are solved per subject from incisal targets (:class:`Subject`), so the incisal ranges
hold for any geometry.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from scipy.optimize import brentq

from facesim import se3
from facesim.errors import FacesimError
from facesim.model import JawGeometry

UP = (0.0, 1.0, 0.0)           # facesim's skull up axis (README: y up, z toward the nose)
_EPS_L = 0.15                  # width of the smooth positive part of the laterality
_EPS_S = 1.0                   # mm, width of the smooth max in the protrusion slide
_RESERVE = 2.0                 # mm of eminence beyond the slide at maximum opening
BORDER_CURVES = ("posterior", "anterior", "right_posterior", "left_posterior",
                 "right_anterior", "left_anterior")


@dataclass(frozen=True)
class Subject:
    """Per-subject jaw-motion parameters: incisal targets (mm) and joint shape.

    hinge_opening : mm, vertical incisal opening reached by pure rotation (17-20).
    max_opening : mm, maximum vertical incisal opening (46-51).
    condyle_translation : mm, condylar slide along the eminence at maximum opening (12-20).
    protrusion : mm, forward incisal travel at maximum protrusion in tooth contact (8-9).
    lateral_excursion : mm, sideways incisal travel at maximum laterotrusion (9-12).
    bennett_shift : mm, side shift of the mandible toward the working side at full laterotrusion.
    eminence_inclination : rad below the horizontal of the eminence chord (30-45 degrees), or
        None for the geometry's ``track_direction``.
    eminence_curvature : rad, the path tangent turns from +delta to −delta (module docstring).
    incisal_drop, canine_drop : mm, incisor drop guided by the teeth at maximum protrusion /
        laterotrusion.
    working_retreat : fraction kappa of its slide the working condyle gives back laterally.
    hysteresis : mm, condylar lead on opening (and lag on closing) in mid translation.
    distraction : mm, how far below its closing path a condyle rides while opening (joint
        play: the same incisal position is reached by slightly different poses).
    """

    hinge_opening: float = 18.5
    max_opening: float = 48.5
    condyle_translation: float = 15.0
    protrusion: float = 8.5
    lateral_excursion: float = 10.5
    bennett_shift: float = 1.0
    eminence_inclination: float | None = None
    eminence_curvature: float = 0.2
    incisal_drop: float = 2.5
    canine_drop: float = 2.0
    working_retreat: float = 0.45
    hysteresis: float = 0.5
    distraction: float = 0.4

    # anatomical ranges used by ``random`` (docs/physics.md section 3; the last ones are estimates)
    RANGES: ClassVar[dict[str, tuple[float, float]]] = {
        "hinge_opening": (17.0, 20.0),
        "max_opening": (46.5, 50.5),
        "condyle_translation": (12.0, 18.0),
        "protrusion": (8.0, 8.5),
        "lateral_excursion": (9.0, 11.0),
        "bennett_shift": (0.5, 1.5),
        "eminence_inclination": (np.radians(30.0), np.radians(45.0)),
        "eminence_curvature": (0.1, 0.3),
        "incisal_drop": (1.5, 3.5),
        "canine_drop": (1.0, 3.0),
        "working_retreat": (0.42, 0.55),
        "hysteresis": (0.3, 0.7),
        "distraction": (0.2, 0.6),
    }

    def __post_init__(self):
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if value is None and f.name == "eminence_inclination":
                continue
            if not np.isfinite(value) or value < 0:
                raise FacesimError(f"subject.{f.name}: expected a finite value >= 0, got {value}")
        if not 0 < self.hinge_opening < self.max_opening:
            raise FacesimError("subject: expected 0 < hinge_opening < max_opening (mm)")
        if self.condyle_translation <= 0 or self.protrusion <= 0 or self.lateral_excursion <= 0:
            raise FacesimError("subject: condyle_translation, protrusion and lateral_excursion must be > 0 mm")
        if self.eminence_inclination is not None and not 0 < self.eminence_inclination < np.pi / 2:
            raise FacesimError("subject.eminence_inclination: expected an angle in (0, pi/2) rad")
        if not self.working_retreat < 1:
            raise FacesimError("subject.working_retreat: expected a fraction below 1")

    @classmethod
    def random(cls, seed=None) -> Subject:
        """A subject drawn uniformly from ``RANGES`` with ``numpy.random.default_rng(seed)``."""
        rng = np.random.default_rng(seed)
        return cls(**{name: float(rng.uniform(lo, hi)) for name, (lo, hi) in cls.RANGES.items()})


def subject_for(geometry: JawGeometry | None = None, base: Subject | None = None, up=UP) -> Subject:
    """The subject of a face model's own TMJ: ``base`` (default ``Subject()``) with its condylar
    translation within the geometry's ``track_length`` (1 mm short of it) and its hinge and
    maximum openings (mm) scaled by one factor so that the rotation about the intercondylar axis
    at the maximum opening is the geometry's ``max_opening`` (rad): the generated motion stays
    inside the sliding-condyle model's limits, with the subject's proportions.

    geometry : JawGeometry (default the shipped model's ``jaw``); up : the skull's up direction.
    """
    if geometry is None:
        from facesim.jaw._shipped import shipped_model

        geometry = shipped_model().jaw
    base = Subject() if base is None else base
    sub = dataclasses.replace(base, condyle_translation=min(base.condyle_translation, geometry.track_length - 1.0))
    if sub.condyle_translation <= 0:
        raise FacesimError(f"jaw.track_length: {geometry.track_length:g} mm leaves no condylar translation")

    def scaled(k):
        return dataclasses.replace(sub, hinge_opening=k * sub.hinge_opening, max_opening=k * sub.max_opening)

    def excess(k):            # rotation at the maximum opening minus the geometry's, rad (nan: unreachable)
        try:
            return JawMotion(geometry, scaled(k), up).max_rotation - geometry.max_opening
        except FacesimError:
            return np.nan

    # the rotation grows with the openings: walk from k = 1 in steps of 6% to a bracket (openings
    # too large for the geometry are unreachable, nan: walk down past them)
    k, value = 1.0, excess(1.0)
    factor = 1.06 if value < 0 else 1 / 1.06
    lo = hi = k

    def beyond(v):
        return v < 0 if factor > 1 else v > 0

    while (np.isnan(value) and factor < 1 or beyond(value)) and 0.2 < k < 3.0:
        k *= factor
        lo, hi, value = k, lo, excess(k)
    if not np.isfinite(value) or beyond(value) or np.isnan(excess(hi)):
        raise FacesimError(f"jaw.max_opening: {np.degrees(geometry.max_opening):.1f} degrees is not reachable with "
                           f"{sub.condyle_translation:g} mm of condylar translation and a hinge opening "
                           f"{sub.hinge_opening / sub.max_opening:.2f} of the maximum opening")
    return scaled(float(brentq(excess, min(lo, hi), max(lo, hi), xtol=1e-10)))


@dataclass(frozen=True)
class Segment:
    """Frames ``start:stop`` of a session performing the movement ``name``."""

    name: str
    start: int
    stop: int


@dataclass(frozen=True)
class Session:
    """A generated capture session.

    poses : (N, 4, 4) mandible relative to skull, mm (rest pose = identity), noise included.
    times : (N,) s.
    latent : (N, 3) the controls (opening, protrusion, laterality) that made the poses.
    segments : the movements performed (border movements are named after ``BORDER_CURVES``).
    reference_point : (3,) mm, the lower incisal point at rest (skull frame).
    """

    poses: np.ndarray
    times: np.ndarray
    latent: np.ndarray
    segments: tuple[Segment, ...]
    reference_point: np.ndarray

    def frames(self, name: str) -> np.ndarray:
        """Indices of the frames in the segments called ``name`` (empty if none)."""
        idx = [np.arange(s.start, s.stop) for s in self.segments if s.name == name]
        return np.concatenate(idx) if idx else np.zeros(0, dtype=int)

    def save(self, path):
        """Write a poses file (``poses``, ``reference_point``, ``times`` and the segments)."""
        np.savez_compressed(path, poses=self.poses, reference_point=self.reference_point, times=self.times,
                            latent=self.latent, segment_names=np.array([s.name for s in self.segments]),
                            segment_bounds=np.array([[s.start, s.stop] for s in self.segments], dtype=np.int64))


@dataclass(frozen=True)
class _Solved:
    """Joint parameters solved from the incisal targets (rad, mm)."""

    theta_h: float = 0.0
    theta_max: float = 0.5
    slide_open: float = 15.0      # S_o
    slide_top: float = 17.0       # S_top
    slide_p: float = 8.0          # S_p
    theta_p: float = 0.0
    slide_l: float = 10.0         # S_l
    theta_l: float = 0.0


def _pos(x):
    """C¹ positive part of ``x``: 0 below 0, x²/(2e) up to e, then x − e/2; normalised to 1 at 1."""
    x = np.asarray(x, dtype=np.float64)
    e = _EPS_L
    y = np.where(x <= 0, 0.0, np.where(x < e, x * x / (2 * e), x - e / 2))
    return y / (1 - e / 2)


def _softplus(x):
    """Smooth max(x, 0) (mm) of width _EPS_S."""
    return 0.5 * (x + np.sqrt(x * x + _EPS_S**2))


def _min_rotation(a, b):
    """Rotations ``(..., 3, 3)`` taking the unit ``a (3,)`` to the unit ``b (..., 3)`` about a × b."""
    k = np.cross(a, b)
    c = b @ a
    K = se3.hat(k)
    return np.eye(3) + K + (K @ K) / (1.0 + c)[..., None, None]


class JawMotion:
    """Kinematic jaw of one subject: latent controls -> rigid mandible poses, and sessions.

    geometry : JawGeometry (condyles, track direction, incisor; mm), default the shipped
        model's ``jaw``. Only the condyles, the track direction and the incisor are used.
    subject : Subject, default ``Subject()``.
    up : (3,) the skull's up direction (orthogonalised against the intercondylar axis).
    """

    def __init__(self, geometry: JawGeometry | None = None, subject: Subject | None = None, up=UP):
        if geometry is None:
            from facesim.jaw._shipped import shipped_model

            geometry = shipped_model().jaw
        if not isinstance(geometry, JawGeometry):
            raise FacesimError(f"JawMotion: expected a JawGeometry, got {type(geometry).__name__}")
        self.geometry = geometry
        self.subject = Subject() if subject is None else subject
        sub = self.subject
        self.cR, self.cL = geometry.condyle_right.copy(), geometry.condyle_left.copy()
        self.m = 0.5 * (self.cR + self.cL)
        self.u = geometry.u
        up = np.asarray(up, dtype=np.float64)
        y = up - (up @ self.u) * self.u
        if np.linalg.norm(y) < 1e-6:
            raise FacesimError("JawMotion: the up direction is parallel to the intercondylar axis")
        self.up = y / np.linalg.norm(y)
        self.forward = np.cross(self.u, self.up)
        v = geometry.track_direction - (geometry.track_direction @ self.u) * self.u
        incl = np.arctan2(-(v @ self.up), v @ self.forward)
        if sub.eminence_inclination is not None:
            incl = sub.eminence_inclination
        if not 0 < incl < np.pi / 2:
            raise FacesimError(f"jaw.track_direction: expected forward and downward, inclination "
                               f"{np.degrees(incl):.1f} degrees")
        self.inclination = float(incl)
        self.v = np.cos(incl) * self.forward - np.sin(incl) * self.up
        self.n = np.cross(self.v, self.u)
        self.incisor0 = geometry.incisor.copy()
        self._p = self._solve()

    # --- kinematics -----------------------------------------------------------------------------

    def path(self, s) -> np.ndarray:
        """Condyle displacement ``(..., 3)`` mm along the curved eminence after a slide ``s (...)`` mm."""
        s = np.asarray(s, dtype=np.float64)
        L, d = self.subject.condyle_translation, self.subject.eminence_curvature
        if d < 1e-6:
            a, b = s, np.zeros_like(s)
        else:
            psi = d * (1 - 2 * s / L)
            a = L / (2 * d) * (np.sin(d) - np.sin(psi))
            b = L / (2 * d) * (np.cos(d) - np.cos(psi))
        return a[..., None] * self.v + b[..., None] * self.n

    def _state(self, latent, h, p: _Solved):
        o, pr, la = (np.asarray(latent, dtype=np.float64)[..., i] for i in range(3))
        lp, lm = _pos(la), _pos(-la)
        sub = self.subject
        theta = (p.theta_p * pr + p.theta_l * (lp + lm)) * (1 - o) + p.theta_max * o
        r = np.clip((theta - p.theta_h) / (p.theta_max - p.theta_h), 0.0, 1.0)
        s_open = p.slide_open * r * r * (2 - r) + sub.hysteresis * h * 6.75 * r * r * (1 - r)
        s_mid = s_open + pr * _softplus(p.slide_p - s_open)
        extra = p.slide_l * np.clip(1 - s_mid / p.slide_top, 0.0, None) ** 2
        retreat = sub.working_retreat * s_mid
        s_right = s_mid + extra * lp - retreat * lm
        s_left = s_mid + extra * lm - retreat * lp
        shift = sub.bennett_shift * (lp - lm)
        distraction = sub.distraction * 0.5 * (1 + h) * np.sin(np.pi * o)
        return theta, s_right, s_left, shift, distraction

    def _poses(self, latent, h, p: _Solved) -> np.ndarray:
        theta, s_right, s_left, shift, distraction = self._state(latent, h, p)
        CR = self.cR + self.path(s_right) - distraction[..., None] * self.n
        CL = self.cL + self.path(s_left) - distraction[..., None] * self.n
        axis = CL - CR
        axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
        R = _min_rotation(self.u, axis) @ se3.so3_exp(theta[..., None] * self.u)
        t = 0.5 * (CR + CL) + shift[..., None] * self.u - R @ self.m
        return se3.from_rt(R, t)

    def poses(self, latent, direction=None) -> np.ndarray:
        """Rigid poses ``(..., 4, 4)`` (mandible relative to skull, mm) of ``latent (..., 3)`` =
        (opening [0, 1], protrusion [0, 1], laterality [−1, 1]); ``direction (...)`` in [−1, 1]
        is the hysteresis state (+1 opening, −1 closing, default 0)."""
        latent = np.asarray(latent, dtype=np.float64)
        if latent.shape[-1:] != (3,) or not np.isfinite(latent).all():
            raise FacesimError(f"latent: expected (..., 3) finite controls, got shape {latent.shape}")
        lo, hi = np.array([0.0, 0.0, -1.0]), np.array([1.0, 1.0, 1.0])
        if (latent < lo - 1e-9).any() or (latent > hi + 1e-9).any():
            raise FacesimError("latent: expected opening and protrusion in [0, 1], laterality in [-1, 1]")
        h = np.zeros(latent.shape[:-1]) if direction is None else np.asarray(direction, dtype=np.float64)
        return self._poses(latent, h, self._p)

    def measures(self, poses) -> dict[str, np.ndarray]:
        """Incisal displacements from rest of ``poses (N, 4, 4)``, mm: ``opening`` (down),
        ``protrusion`` (forward), ``lateral`` (toward the subject's left), and the ``condyle_slide``
        (N, 2) mm of the right and left condyle from rest."""
        poses = np.asarray(poses, dtype=np.float64)
        d = se3.transform_points(poses, self.incisor0)[..., 0, :] - self.incisor0
        c = se3.transform_points(poses, np.stack([self.cR, self.cL])) - np.stack([self.cR, self.cL])
        return {"opening": -d @ self.up, "protrusion": d @ self.forward, "lateral": d @ self.u,
                "condyle_slide": np.linalg.norm(c, axis=-1)}

    # --- per-subject parameters -----------------------------------------------------------------

    def _solve(self) -> _Solved:
        sub = self.subject
        p = _Solved(slide_open=sub.condyle_translation, slide_top=sub.condyle_translation + _RESERVE)

        def measure(latent, q):
            T = self._poses(np.asarray(latent, dtype=np.float64), 0.0, q)
            d = T[:3, :3] @ self.incisor0 + T[:3, 3] - self.incisor0
            return -d @ self.up, d @ self.forward, d @ self.u

        def bracket(f, lo, hi, what):
            if f(lo) * f(hi) > 0:
                raise FacesimError(f"subject.{what}: not reachable with this jaw geometry")
            return brentq(f, lo, hi, xtol=1e-12)

        def hinge(th):        # pure rotation about the intercondylar axis, no slide
            d = se3.so3_exp(th * self.u) @ (self.incisor0 - self.m) + self.m - self.incisor0
            return -d @ self.up - sub.hinge_opening

        p = dataclasses.replace(p, theta_h=bracket(hinge, 1e-6, 1.0, "hinge_opening"))
        p = dataclasses.replace(p, theta_max=bracket(
            lambda th: measure([1.0, 0.0, 0.0], dataclasses.replace(p, theta_max=th))[0] - sub.max_opening,
            p.theta_h + 1e-3, 1.0, "max_opening"))

        def slide_and_angle(latent, slide, angle, index, target, drop, what):
            """The slide (mm) and contact angle (rad) that put the incisor ``target`` mm along
            measure ``index`` with a tooth-guided drop of ``drop`` mm (nested 1-D solves)."""
            def with_(x, a):
                return dataclasses.replace(p, **{slide: x, angle: a})

            def angle_for(x):
                return bracket(lambda a: measure(latent, with_(x, a))[0] - drop, -0.4, 0.4, what)

            x = bracket(lambda x: measure(latent, with_(x, angle_for(x)))[index] - target, 0.05, 40.0, what)
            return with_(x, angle_for(x))

        p = slide_and_angle([0.0, 1.0, 0.0], "slide_p", "theta_p", 1, sub.protrusion, sub.incisal_drop, "protrusion")
        return slide_and_angle([0.0, 0.0, 1.0], "slide_l", "theta_l", 2, sub.lateral_excursion, sub.canine_drop,
                               "lateral_excursion")

    @property
    def hinge_angle(self) -> float:
        """rad, rotation at the end of the pure-hinge opening."""
        return self._p.theta_h

    @property
    def max_rotation(self) -> float:
        """rad, rotation about the intercondylar axis at maximum opening."""
        return self._p.theta_max

    # --- sessions -------------------------------------------------------------------------------

    def session(self, seed=0, kinds=("border", "chewing", "speech", "free"), fps: float = 30.0,
                noise: float = 0.0, speed: float = 1.0) -> Session:
        """A capture-like session: the movements ``kinds`` in order, each a smooth latent path.

        ``border``: Posselt envelope tracing (retruded hinge and posterior border, protrusion and
        anterior border, right and left laterals, the four lateral vertical borders, the contact
        rim); ``chewing``: teardrop chewing cycles on one side; ``speech``: small fast openings;
        ``free``: random moves inside the envelope. ``seed`` sets durations and amplitudes,
        ``noise`` (mm) the standard deviation of a capture error applied to every pose (translation
        std ``noise`` mm, rotation std ``noise / 100`` rad), ``speed`` scales all tempos.
        """
        if not fps > 0 or not speed > 0 or not noise >= 0:
            raise FacesimError("session: expected fps > 0, speed > 0 and noise >= 0")
        rng = np.random.default_rng(seed)
        builders = {"border": _border_moves, "chewing": _chewing_moves, "speech": _speech_moves,
                    "free": _free_moves}
        moves: list[tuple[str, float, np.ndarray]] = []
        for kind in kinds:
            if kind not in builders:
                raise FacesimError(f"session: unknown movement {kind!r} (expected one of {', '.join(builders)})")
            moves += builders[kind](rng)
        latent, names = _sample(moves, fps / speed)
        times = np.arange(len(latent)) / fps
        rate = np.gradient(latent[:, 0], times) if len(latent) > 1 else np.zeros(1)
        direction = np.tanh(rate / 0.3)
        poses = self._poses(latent, direction, self._p)
        if noise > 0:
            xi = np.concatenate([rng.normal(scale=noise / 100.0, size=(len(poses), 3)),
                                 rng.normal(scale=noise, size=(len(poses), 3))], axis=1)
            poses = poses @ se3.exp(xi)
        segments, start = [], 0
        for i in range(1, len(names) + 1):
            if i == len(names) or names[i] != names[start]:
                segments.append(Segment(names[start], start, i))
                start = i
        return Session(poses=poses, times=times, latent=latent, segments=tuple(segments),
                       reference_point=self.incisor0.copy())


# --- latent paths: lists of (label, duration s, target latent) ---------------------------------

def _border_moves(rng):
    def T():
        return float(rng.uniform(1.6, 2.4))

    def t():
        return float(rng.uniform(0.7, 1.1))

    k = np.array
    moves = [("rest", 0.4, k([0, 0, 0]))]
    # vertical tracings: out to the maximum opening and back, at fixed protrusion and laterality
    for name, p, la in [("posterior", 0, 0), ("anterior", 1, 0), ("right_posterior", 0, -1),
                        ("right_anterior", 1, -1), ("left_anterior", 1, 1), ("left_posterior", 0, 1)]:
        moves += [("contact", t(), k([0, p, la])), (name, T(), k([1, p, la])), (name, T(), k([0, p, la]))]
    # contact rim: protrusion, laterals and the protrusive-lateral corners
    moves += [("contact", t(), k([0, 0, 0])), ("protrusion", t(), k([0, 1, 0])), ("protrusion", t(), k([0, 0, 0])),
              ("right_lateral", t(), k([0, 0, -1])), ("contact", t(), k([0, 1, -1])),
              ("contact", T(), k([0, 1, 1])), ("contact", t(), k([0, 0, 1])),
              ("left_lateral", t(), k([0, 0, 0]))]
    return moves


def _chewing_moves(rng):
    side = rng.choice([-1.0, 1.0])
    moves = []
    for _ in range(int(rng.integers(7, 10))):
        period = rng.uniform(0.65, 0.9)
        o, la, p = rng.uniform(0.22, 0.4), side * rng.uniform(0.3, 0.6), rng.uniform(0.0, 0.2)
        # teardrop in the frontal plane: open near the midline, close from the working side
        moves += [("chewing", 0.4 * period, np.array([o, p, -0.15 * la])),
                  ("chewing", 0.35 * period, np.array([0.35 * o, 0.5 * p, la])),
                  ("chewing", 0.25 * period, np.array([0.0, 0.0, 0.0]))]
        if rng.uniform() < 0.2:
            side = -side
    return moves


def _speech_moves(rng):
    moves = []
    for _ in range(int(rng.integers(28, 36))):
        o = rng.uniform(0.02, 0.3)
        moves.append(("speech", rng.uniform(0.12, 0.3),
                      np.array([o, rng.uniform(0.0, 0.3), rng.uniform(-0.1, 0.1)])))
    moves.append(("speech", 0.3, np.zeros(3)))
    return moves


def _free_moves(rng):
    moves = [("free", rng.uniform(0.7, 1.4), np.array([rng.uniform(0, 1), rng.uniform(0, 1), rng.uniform(-1, 1)]))
             for _ in range(int(rng.integers(14, 18)))]
    moves.append(("free", 1.0, np.zeros(3)))
    return moves


def _sample(moves, fps: float):
    """Latent samples ``(N, 3)`` at ``fps`` along minimum-jerk moves from rest, and their labels."""
    current = np.zeros(3)
    out, names = [np.zeros((1, 3))], ["rest"]
    for name, duration, target in moves:
        n = max(1, round(duration * fps))
        tau = np.arange(1, n + 1) / n
        blend = tau**3 * (10 - 15 * tau + 6 * tau**2)        # minimum jerk: zero speed and acceleration at the ends
        out.append(current + blend[:, None] * (np.asarray(target, dtype=np.float64) - current))
        names += [name] * n
        current = np.asarray(target, dtype=np.float64)
    return np.concatenate(out), names


__all__ = ["BORDER_CURVES", "UP", "JawMotion", "Segment", "Session", "Subject", "subject_for"]
