"""A procedural lip occluder: the face around an open mouth, as a surface in front of the teeth.

The surface wraps the dental arch ``GAP_MM`` in front of it (a parabola ``z = a - b x^2`` fitted
to the front of the teeth seen from above) and is cut by the mouth opening: a closed curve
between the mouth corners at ``x = +-half_width`` whose upper lip edge lies over the upper teeth
(at the midline ``cover_upper`` mm above the upper incisal point, which moves with the head)
and whose lower lip edge is ``cover_lower`` mm below the lower
incisal point (which moves with the jaw): the opening follows the jaw. A negative
``cover_lower`` raises the lower lip over the lower teeth (they are hidden). The surface is
rings of quads from the opening out to a rectangle far beyond the teeth, all moved with the head.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from facesim import se3

#: The lips' surface lies this far in front of the teeth (mm).
GAP_MM = 4.0
#: Points on the opening's curve and rings out to the outer rectangle.
CONTOUR_POINTS = 160
RINGS = 10
#: The lips curve less than the dental arch (a share of the arch's curvature): a side camera
#: still sees both mouth corners.
LIP_CURVATURE = 0.5


@dataclass(frozen=True)
class LipOccluder:
    """The occluder of a dentition (see the module docstring).

    a, b : the sheet ``z = a - b x^2`` mm (skull frame), ``a`` including ``GAP_MM``.
    x_clamp : mm, beyond it the sheet keeps the depth it has at ``+-x_clamp``.
    half_width : mm, the mouth corners' x. upper_incisor, lower_incisor : (3,) mm at rest.
    extent : (x, down, up) mm, the outer rectangle around the mouth.
    """

    a: float
    b: float
    x_clamp: float
    half_width: float
    upper_incisor: np.ndarray
    lower_incisor: np.ndarray
    extent: tuple[float, float, float] = (160.0, 140.0, 100.0)

    @classmethod
    def of(cls, dentition, half_width: float = 26.0) -> LipOccluder:
        """The occluder in front of ``dentition`` (:class:`~facesim.teeth.dentition.Dentition`)."""
        V = np.concatenate([dentition.upper_V, dentition.lower_V])
        V = V[np.abs(V[:, 0]) < 0.6 * half_width]   # the front of the arch: incisors and canines
        bins = np.linspace(V[:, 0].min(), V[:, 0].max(), 25)
        which = np.digitize(V[:, 0], bins)
        xs, zs = [], []
        for k in np.unique(which):   # 25 bins: the front of the arch seen from above
            sel = which == k
            i = np.argmax(V[sel, 2])
            xs.append(V[sel][i, 0])
            zs.append(V[sel][i, 2])
        xs, zs = np.array(xs), np.array(zs)
        # least squares z = a - b x^2, shifted so every front point is behind the sheet
        A = np.column_stack([np.ones_like(xs), -xs * xs])
        a, b = np.linalg.lstsq(A, zs, rcond=None)[0]
        b *= LIP_CURVATURE
        a += max(0.0, float((zs - (a - b * xs * xs)).max())) + GAP_MM
        return cls(float(a), float(max(b, 0.0)), float(half_width), float(half_width),
                   np.asarray(dentition.upper_incisor, dtype=np.float64),
                   np.asarray(dentition.incisor, dtype=np.float64))

    def faces(self) -> np.ndarray:
        """``(m, 3) int32`` triangles of the surface (the same for every frame)."""
        K = CONTOUR_POINTS
        tris = []
        for r in range(RINGS):
            i = r * K + np.arange(K)
            j = r * K + (np.arange(K) + 1) % K
            tris += [np.column_stack([i, j, i + K]), np.column_stack([j, j + K, i + K])]
        return np.concatenate(tris).astype(np.int32)

    def vertices(self, jaw, head=None, cover_upper: float = 3.0, cover_lower: float = 4.0,
                 hide_lower: bool = False) -> np.ndarray:
        """``((RINGS + 1) * CONTOUR_POINTS, 3)`` world vertices mm for the jaw pose ``jaw (4, 4)``
        (skull frame), the head pose ``head (4, 4)`` (default identity) and the lip covers (mm);
        ``hide_lower``: the lower lip rises to 1 mm below the upper incisal edge, over all the
        lower teeth however far the jaw opens."""
        top = self.upper_incisor[1] + cover_upper
        low = se3.transform_points(jaw, self.lower_incisor[None])[0, 1] - cover_lower
        if hide_lower:
            low = self.upper_incisor[1] - 1.0
        yc = 0.5 * (top + low)
        h = max(0.5 * (top - low), 0.05)                    # a closed mouth keeps a sliver
        phi = np.linspace(0.0, 2.0 * np.pi, CONTOUR_POINTS, endpoint=False)
        c, s = np.cos(phi), np.sin(phi)
        inner = np.column_stack([self.half_width * c, yc + h * np.sign(s) * np.abs(s) ** 0.7])
        X, down, up = self.extent
        # the outer rectangle along the same directions from the mouth's centre
        with np.errstate(divide="ignore"):
            k = np.minimum(np.where(np.abs(c) > 1e-9, X / np.abs(c), np.inf),
                           np.where(s > 1e-9, (up + h) / s, np.where(s < -1e-9, (down + h) / -s, np.inf)))
        outer = np.column_stack([k * c, yc + k * s])
        t = np.linspace(0.0, 1.0, RINGS + 1) ** 1.5           # finer rings near the lips
        P = (1.0 - t)[:, None, None] * inner[None] + t[:, None, None] * outer[None]
        P = P.reshape(-1, 2)
        x = np.clip(P[:, 0], -self.x_clamp, self.x_clamp)
        V = np.column_stack([P[:, 0], P[:, 1], self.a - self.b * x * x])
        return V if head is None else se3.transform_points(head, V)


__all__ = ["GAP_MM", "LipOccluder"]
