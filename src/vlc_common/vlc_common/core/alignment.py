"""Horizontal track alignment: chainage s → (x, y, heading ψ, curvature κ) in ``map``.

An alignment is a chain of elements, each with a curvature that is linear in chainage
(the three elements of railway horizontal design):

* ``straight``: κ = 0;
* ``arc`` (circular curve): κ = ±1/R constant (positive = curving left, toward +y at
  ψ = 0, REP-103);
* ``clothoid`` (transition spiral): κ changes linearly from the previous element's
  curvature to the given end curvature, so curvature — hence lateral acceleration and
  yaw rate — has no jump.

Heading and curvature are exact (ψ = ψ0 + κ0·u + ½κ'·u², u = s − s0); positions are
exact for straights and arcs (closed form) and for clothoids a 20-node Gauss–Legendre
quadrature of ∫(cos ψ, sin ψ)du, exact to rounding for the heading changes of a
transition (< 0.5 rad; the quadrature error for a polynomial phase spanning θ rad is of
order θ⁴⁰/40!).

Chainages outside the alignment continue along the first and last elements, which must
be straights: the alignment is defined for every real s. Frames: ``map`` x along the
chainage at the start (ψ = 0 there for the default), y left, z up; the track's left
normal is n(s) = (−sin ψ, cos ψ).

The default alignment is the straight line along map x through the origin (s = x),
reproducing the straight-tunnel rig exactly. Named alignments (:data:`NAMED_ALIGNMENTS`)
are selected by the rig parameter ``alignment``.
"""
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

_GL_NODES, _GL_WEIGHTS = np.polynomial.legendre.leggauss(20)
#: Spacing of the coarse table used to start the projection's Newton iterations, m.
_PROJECTION_TABLE_STEP_M = 1.0
#: Table margin beyond the first and last element (extension straights), m.
_PROJECTION_TABLE_MARGIN_M = 500.0


@dataclass
class AlignmentPoint:
    """Alignment evaluated at N chainages (arrays of shape (N,)).

    Attributes
    ----------
    chainage_m : ndarray
        s, m.
    x_m, y_m : ndarray
        Centreline position in ``map``, m.
    heading_rad : ndarray
        ψ, angle of the running direction from map x toward map y, rad.
    curvature_1pm : ndarray
        κ = dψ/ds, 1/m (positive: curving left).
    curvature_rate_1pm2 : ndarray
        dκ/ds, 1/m² (non-zero on clothoids only).
    """

    chainage_m: np.ndarray
    x_m: np.ndarray
    y_m: np.ndarray
    heading_rad: np.ndarray
    curvature_1pm: np.ndarray
    curvature_rate_1pm2: np.ndarray

    @property
    def tangent(self):
        """Unit running direction (N, 2) in map x, y."""
        return np.stack([np.cos(self.heading_rad), np.sin(self.heading_rad)], axis=1)

    @property
    def left_normal(self):
        """Unit left normal (N, 2) in map x, y (toward the left wall)."""
        return np.stack([-np.sin(self.heading_rad), np.cos(self.heading_rad)], axis=1)


class Alignment:
    """A horizontal alignment; see the module docstring.

    Parameters
    ----------
    elements : sequence of tuple
        ``('straight', length_m)``, ``('arc', length_m, radius_m)`` (radius signed:
        positive curves left) or ``('clothoid', length_m, end_radius_m)`` (end radius
        signed; ``float('inf')`` or 0 for a transition back to straight). The first and
        last elements must be straights (they are also extended beyond the ends).
    start_chainage_m : float
        Chainage at the start of the first element, m.
    start_xy_m : (float, float)
        Map position at the start, m.
    start_heading_rad : float
        Heading at the start, rad.
    name : str
        Label (the rig parameter value that selects it).
    """

    def __init__(self, elements, start_chainage_m=0.0, start_xy_m=(0.0, 0.0),
                 start_heading_rad=0.0, name='custom'):
        elements = [tuple(e) for e in elements]
        if not elements or elements[0][0] != 'straight' or elements[-1][0] != 'straight':
            raise ValueError('an alignment must start and end with a straight element')
        self.name = name
        self.elements = elements
        rows = []            # s0, length, x0, y0, psi0, k0, k1
        s, x, y, psi, k = float(start_chainage_m), *map(float, start_xy_m), \
            float(start_heading_rad), 0.0
        for element in elements:
            kind, length = element[0], float(element[1])
            if not np.isfinite(length) or length < 0.0 or (kind != 'straight' and length <= 0.0):
                raise ValueError(f'element {element}: length must be finite and > 0 '
                                 '(>= 0 for a straight)')
            if kind == 'straight':
                if k != 0.0:
                    raise ValueError(f'element {element}: a straight must follow a zero-'
                                     'curvature end (add a clothoid back to straight)')
                k0 = k1 = 0.0
            elif kind == 'arc':
                k0 = k1 = _curvature_of(element[2], element)
                if k0 == 0.0:
                    raise ValueError(f'element {element}: an arc needs a finite radius')
                if k != k0:
                    raise ValueError(f'element {element}: curvature jumps from {k:g} to '
                                     f'{k0:g} 1/m (a clothoid must lead into the arc)')
            elif kind == 'clothoid':
                k0, k1 = k, _curvature_of(element[2], element)
                if k0 == k1:
                    raise ValueError(f'element {element}: a clothoid must change curvature')
            else:
                raise ValueError(f'unknown alignment element {kind!r}: expected straight, '
                                 'arc or clothoid')
            rows.append((s, length, x, y, psi, k0, k1))
            x, y = self._advance(kind, length, x, y, psi, k0, k1)
            psi += 0.5 * (k0 + k1) * length          # κ linear: mean curvature × length
            s += length
            k = k1
        self._rows = np.array(rows, dtype=float)
        self._kinds = np.array([{'straight': 0, 'arc': 1, 'clothoid': 2}[e[0]]
                                for e in elements])
        self.start_chainage_m = float(start_chainage_m)
        self.end_chainage_m = s
        self._tree = None

    # ------------------------------------------------------------------ factories
    @classmethod
    def straight(cls):
        """The default: the straight line along map x through the origin, s = x."""
        return cls([('straight', 0.0)], name='straight')

    @classmethod
    def named(cls, name):
        """A named alignment of :data:`NAMED_ALIGNMENTS` (ValueError if unknown)."""
        if name not in NAMED_ALIGNMENTS:
            raise ValueError(f'unknown alignment {name!r}: expected one of '
                             f'{", ".join(sorted(NAMED_ALIGNMENTS))}')
        spec = NAMED_ALIGNMENTS[name]
        if spec is None:
            return cls.straight()
        return cls(spec, name=name)

    @property
    def is_straight(self):
        """True when the alignment has no curvature anywhere."""
        return bool(np.all(self._kinds == 0))

    @property
    def length_m(self):
        return self.end_chainage_m - self.start_chainage_m

    # ------------------------------------------------------------------ evaluation
    @staticmethod
    def _advance(kind, u, x0, y0, psi0, k0, k1):
        """Position after ``u`` metres of one element (scalars)."""
        p = Alignment._offset(np.array([kind]), np.array([u], float), psi0, k0,
                              (k1 - k0) / u if kind == 'clothoid' else 0.0)
        return x0 + p[0, 0], y0 + p[0, 1]

    @staticmethod
    def _offset(kinds, u, psi0, k0, dk):
        """Offset (N, 2) from an element's start after ``u`` m (kinds 'straight' …)."""
        u = np.asarray(u, float)
        psi0, k0, dk = (np.broadcast_to(np.asarray(a, float), u.shape) for a in (psi0, k0, dk))
        out = np.empty(u.shape + (2,))
        straight = kinds == 'straight'
        arc = kinds == 'arc'
        clothoid = kinds == 'clothoid'
        if np.any(straight):
            out[straight, 0] = u[straight] * np.cos(psi0[straight])
            out[straight, 1] = u[straight] * np.sin(psi0[straight])
        if np.any(arc):
            p0, k, uu = psi0[arc], k0[arc], u[arc]
            out[arc, 0] = (np.sin(p0 + k * uu) - np.sin(p0)) / k
            out[arc, 1] = (np.cos(p0) - np.cos(p0 + k * uu)) / k
        if np.any(clothoid):
            p0, k, d, uu = psi0[clothoid], k0[clothoid], dk[clothoid], u[clothoid]
            tau = 0.5 * uu[:, None] * (_GL_NODES[None, :] + 1.0)       # (M, 20) in [0, u]
            phase = p0[:, None] + k[:, None] * tau + 0.5 * d[:, None] * tau * tau
            w = 0.5 * uu[:, None] * _GL_WEIGHTS[None, :]
            out[clothoid, 0] = np.sum(w * np.cos(phase), axis=1)
            out[clothoid, 1] = np.sum(w * np.sin(phase), axis=1)
        return out

    def evaluate(self, chainage_m):
        """The alignment at chainages ``chainage_m`` (scalar or (N,)): AlignmentPoint."""
        s = np.atleast_1d(np.asarray(chainage_m, dtype=float))
        rows = self._rows
        i = np.clip(np.searchsorted(rows[:, 0], s, side='right') - 1, 0, len(rows) - 1)
        s0, length, x0, y0, psi0, k0, k1 = rows[i].T
        u = s - s0
        kinds = np.array(['straight', 'arc', 'clothoid'])[self._kinds[i]]
        clothoid = kinds == 'clothoid'
        dk = np.where(clothoid, (k1 - k0) / np.where(clothoid, length, 1.0), 0.0)
        offset = self._offset(kinds, u, psi0, k0, dk)
        # On a straight k0 = dk = 0 exactly, so ψ stays ψ0 to the bit.
        heading = psi0 + k0 * u + 0.5 * dk * u * u
        return AlignmentPoint(chainage_m=s, x_m=x0 + offset[:, 0], y_m=y0 + offset[:, 1],
                              heading_rad=heading, curvature_1pm=k0 + dk * u,
                              curvature_rate_1pm2=dk)

    def to_map(self, chainage_m, lateral_m=0.0, height_m=0.0):
        """Map points (N, 3) at ``lateral_m`` left of the centreline and ``height_m`` up."""
        p = self.evaluate(chainage_m)
        lateral = np.broadcast_to(np.asarray(lateral_m, float), p.x_m.shape)
        xy = np.stack([p.x_m, p.y_m], axis=1) + lateral[:, None] * p.left_normal
        return np.column_stack([xy, np.broadcast_to(np.asarray(height_m, float), p.x_m.shape)])

    # ------------------------------------------------------------------ inverse
    def _table(self):
        if self._tree is None:
            lo = self.start_chainage_m - _PROJECTION_TABLE_MARGIN_M
            hi = self.end_chainage_m + _PROJECTION_TABLE_MARGIN_M
            s = np.arange(lo, hi + _PROJECTION_TABLE_STEP_M, _PROJECTION_TABLE_STEP_M)
            p = self.evaluate(s)
            self._table_s = s
            self._tree = cKDTree(np.column_stack([p.x_m, p.y_m]))
        return self._tree

    def project(self, x_m, y_m, iterations=8):
        """Inverse of :meth:`to_map` in the plane: map (x, y) → (chainage, lateral offset).

        The foot of the perpendicular from the point to the centreline: the nearest
        entry of a 1 m table (k-d tree) starts Newton iterations on
        g(s) = (p − P(s))·t(s) = 0, g'(s) = −1 + κ(s)·(p − P(s))·n(s). Unique for
        points closer to the track than the smallest radius; far beyond the ends the
        extension straights take over.

        Parameters
        ----------
        x_m, y_m : array_like (N,)
            Map coordinates, m.

        Returns
        -------
        chainage_m, lateral_m : ndarray (N,)
            Chainage of the foot point (m) and signed offset to the left of the
            centreline (m).
        """
        x = np.atleast_1d(np.asarray(x_m, dtype=float))
        y = np.atleast_1d(np.asarray(y_m, dtype=float))
        if self.is_straight and len(self._rows) == 1:
            r = self._rows[0]
            c, sn = np.cos(r[4]), np.sin(r[4])
            dx, dy = x - r[2], y - r[3]
            return r[0] + dx * c + dy * sn, -dx * sn + dy * c
        _, idx = self._table().query(np.column_stack([x, y]))
        s = self._table_s[idx]
        for _ in range(iterations):
            p = self.evaluate(s)
            dx, dy = x - p.x_m, y - p.y_m
            t, n = p.tangent, p.left_normal
            along = dx * t[:, 0] + dy * t[:, 1]
            across = dx * n[:, 0] + dy * n[:, 1]
            step = along / (1.0 - p.curvature_1pm * across)
            s = s + step
            if np.all(np.abs(step) < 1e-10):
                break
        p = self.evaluate(s)
        n = p.left_normal
        return s, (x - p.x_m) * n[:, 0] + (y - p.y_m) * n[:, 1]

    # ------------------------------------------------------------------ templates
    def curvature_template(self, spacing_m=1.0, start_m=None, end_m=None):
        """Curvature sampled every ``spacing_m`` from ``start_m`` to ``end_m``.

        Defaults: the alignment's own extent. Returns (chainage (N,), κ (N,) 1/m).
        """
        start = self.start_chainage_m if start_m is None else float(start_m)
        end = self.end_chainage_m if end_m is None else float(end_m)
        n = int(np.floor((end - start) / spacing_m + 1e-9)) + 1
        s = start + spacing_m * np.arange(n)
        return s, self.evaluate(s).curvature_1pm


def _curvature_of(radius_m, element):
    r = float(radius_m)
    if r == 0.0 or np.isinf(r):
        return 0.0
    if not np.isfinite(r):
        raise ValueError(f'element {element}: radius must be a number')
    return 1.0 / r


#: Named alignments: element lists for :class:`Alignment` (None = the default straight).
#: ``curved_demo`` (2310 m): the radii 300–800 m of metro practice, left and right curves
#: turning by different angles (40°, −23°, 21°, −53°), transitions of 60–100 m, a reverse
#: curve, and straights of 150–300 m between; the heading stays within −15°…+40°, so map
#: x grows monotonically with chainage (the renderer's lamp search window runs along
#: map x).
NAMED_ALIGNMENTS = {
    'straight': None,
    'curved_demo': [
        ('straight', 200.0),
        ('clothoid', 80.0, 400.0),
        ('arc', 200.0, 400.0),
        ('clothoid', 80.0, float('inf')),
        ('straight', 300.0),
        ('clothoid', 60.0, -600.0),
        ('arc', 180.0, -600.0),
        ('clothoid', 60.0, float('inf')),
        ('straight', 150.0),
        ('clothoid', 100.0, 800.0),
        ('arc', 200.0, 800.0),
        ('clothoid', 100.0, float('inf')),
        ('clothoid', 70.0, -300.0),
        ('arc', 210.0, -300.0),
        ('clothoid', 70.0, float('inf')),
        ('straight', 250.0),
    ],
}
