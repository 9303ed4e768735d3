"""Track alignment: chainage s → (x, y, heading ψ, curvature κ) in ``map``, and optionally
elevation z, grade and cant.

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

**Vertical profile and cant** (both optional, zero by default, so a plain element list
is the level, uncanted alignment of before). Chainage stays the *horizontal* (plan)
distance, as in railway alignment design; elevations are functions of it.

* ``vertical_profile``: points of vertical intersection (PVI) ``(s_i, z_i, R_i)``:
  constant grades g between consecutive PVIs, joined at every interior PVI by a parabolic
  vertical curve of length L = R·|Δg| centred on the PVI (the standard design element:
  z'' = Δg/L = ±1/R, the curvature of a circle of radius R to first order). Before the
  first and after the last PVI the profile continues with the first and last grade.
* ``cant_m``: the applied cant (superelevation: height of the outer rail above the inner,
  m, ≥ 0), one value per element, meaning the cant at the element's end: 0 on straights,
  constant on an arc (equal to the end of the transition leading into it), ramped
  linearly along a clothoid from the previous element's value to its own — so, with κ
  linear there, cant stays proportional to curvature through the transition, the usual
  straight-line cant ramp. The cant banks the track toward the curve's centre: the roll
  of the track plane about the running direction is φ = −sign(κ)·asin(D / b) with
  b = ``rail_centre_distance_m`` (1.5 m between the rail-head centres of 1435 mm gauge;
  REP-103 roll: positive lifts the left side, so a left curve has φ < 0). The cant
  rotates the track about its centreline at rail level, where z(s) is given.

:func:`design_cant_m` gives the cant a metro designer would apply for a design speed and
radius; ``curved_demo`` uses it (:data:`NAMED_TRACK_PROFILES`).
"""
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

_GL_NODES, _GL_WEIGHTS = np.polynomial.legendre.leggauss(20)
#: Spacing of the coarse table used to start the projection's Newton iterations, m.
_PROJECTION_TABLE_STEP_M = 1.0
#: Table margin beyond the first and last element (extension straights), m.
_PROJECTION_TABLE_MARGIN_M = 500.0
#: Distance between the rail-head centres of standard (1435 mm) gauge track, m: the base
#: over which cant is measured (EN 13803-1 uses 1500 mm for standard gauge).
RAIL_CENTRE_DISTANCE_M = 1.5
#: Standard gravity, m/s².
_GRAVITY_MPS2 = 9.80665


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
    elevation_m : ndarray
        z(s), height of the centreline at rail level in ``map``, m (0 without a vertical
        profile).
    grade : ndarray
        G = dz/ds, dimensionless (positive: rising with chainage; 0.03 = 3 %).
    grade_rate_1pm : ndarray
        dG/ds = d²z/ds², 1/m (±1/R on vertical curves, 0 elsewhere).
    cant_m : ndarray
        Signed applied cant D, m: positive banks the track for a left curve (right rail
        higher).
    cant_rad : ndarray
        φ = −asin(D / b), roll of the track plane about the running direction, rad
        (REP-103 sign: positive lifts the left side).
    cant_rate_radpm : ndarray
        dφ/ds, rad/m (non-zero on cant ramps).
    cant_rate2_radpm2 : ndarray
        d²φ/ds², rad/m² (from the asin; D itself is linear on a ramp).
    """

    chainage_m: np.ndarray
    x_m: np.ndarray
    y_m: np.ndarray
    heading_rad: np.ndarray
    curvature_1pm: np.ndarray
    curvature_rate_1pm2: np.ndarray
    elevation_m: np.ndarray = None
    grade: np.ndarray = None
    grade_rate_1pm: np.ndarray = None
    cant_m: np.ndarray = None
    cant_rad: np.ndarray = None
    cant_rate_radpm: np.ndarray = None
    cant_rate2_radpm2: np.ndarray = None

    @property
    def pitch_rad(self):
        """Track pitch −atan(G), rad (REP-103: positive pitch lowers the nose)."""
        return -np.arctan(self.grade)

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
    vertical_profile : sequence of tuple or None
        PVIs ``(chainage_m, elevation_m, vertical_curve_radius_m)`` in increasing
        chainage (at least two; the radius of the first and last is not used; a grade
        change needs a radius > 0). None: level at elevation 0.
    cant_m : sequence of float or None
        Applied cant at the end of each element, m (see the module docstring). None: no
        cant.
    rail_centre_distance_m : float
        b, distance between the rail-head centres, m (1.5 m for 1435 mm gauge).
    """

    def __init__(self, elements, start_chainage_m=0.0, start_xy_m=(0.0, 0.0),
                 start_heading_rad=0.0, name='custom', vertical_profile=None, cant_m=None,
                 rail_centre_distance_m=RAIL_CENTRE_DISTANCE_M):
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
        self.rail_centre_distance_m = float(rail_centre_distance_m)
        self._cant = None if cant_m is None else self._cant_rows(cant_m)
        self._vertical = (None if vertical_profile is None
                          else _vertical_rows(vertical_profile))

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
        return cls(spec, name=name, **NAMED_TRACK_PROFILES.get(name, {}))

    @property
    def is_straight(self):
        """True when the alignment has no curvature anywhere."""
        return bool(np.all(self._kinds == 0))

    @property
    def is_level(self):
        """True without a vertical profile and without cant (z = grade = cant = 0)."""
        return self._vertical is None and self._cant is None

    def _cant_rows(self, cant_m):
        """Signed cant (start, end) of every element, m, after the checks of the docstring."""
        cant = [float(c) for c in cant_m]
        if len(cant) != len(self.elements):
            raise ValueError(f'cant_m has {len(cant)} values for {len(self.elements)} '
                             'elements (one per element: the cant at its end)')
        b = self.rail_centre_distance_m
        rows, previous = [], 0.0
        for element, k1, c in zip(self.elements, self._rows[:, 6], cant):
            if not np.isfinite(c) or c < 0.0 or c >= b:
                raise ValueError(f'element {element}: cant {c:g} m must be >= 0 and below '
                                 f'the rail centre distance {b:g} m')
            end = float(np.sign(k1)) * c
            if element[0] == 'straight' and c != 0.0:
                raise ValueError(f'element {element}: a straight has no cant')
            if element[0] == 'clothoid' and k1 == 0.0 and c != 0.0:
                raise ValueError(f'element {element}: a transition back to straight must '
                                 'end at cant 0')
            if element[0] == 'arc' and end != previous:
                raise ValueError(f'element {element}: cant jumps from {abs(previous):g} to '
                                 f'{c:g} m (the transition must ramp to the arc\'s cant)')
            rows.append((previous, end))
            previous = end
        return np.array(rows, dtype=float)

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
        if self._vertical is None:
            z, grade, grade_rate = (np.zeros_like(s) for _ in range(3))
        else:
            z, grade, grade_rate = _evaluate_vertical(self._vertical, s)
        if self._cant is None:
            cant, phi, phi_s, phi_ss = (np.zeros_like(s) for _ in range(4))
        else:
            # Straights (also the extensions beyond the ends) have c0 = c1 = 0.
            c0, c1 = self._cant[i].T
            slope = np.where(length > 0.0, (c1 - c0) / np.where(length > 0.0, length, 1.0),
                             0.0)
            cant = c0 + slope * u
            x = cant / self.rail_centre_distance_m
            x_s = slope / self.rail_centre_distance_m
            root = np.sqrt(1.0 - x * x)
            phi = -np.arcsin(x)                             # banked toward the centre
            phi_s = -x_s / root
            phi_ss = -x * x_s * x_s / root ** 3             # D'' = 0 on a linear ramp
        return AlignmentPoint(chainage_m=s, x_m=x0 + offset[:, 0], y_m=y0 + offset[:, 1],
                              heading_rad=heading, curvature_1pm=k0 + dk * u,
                              curvature_rate_1pm2=dk, elevation_m=z, grade=grade,
                              grade_rate_1pm=grade_rate, cant_m=cant, cant_rad=phi,
                              cant_rate_radpm=phi_s, cant_rate2_radpm2=phi_ss)

    def to_map(self, chainage_m, lateral_m=0.0, height_m=0.0):
        """Map points (N, 3) at ``lateral_m`` left of the centreline and ``height_m`` up.

        Heights are above the centreline's elevation z(s) at rail level; lateral offsets
        run along the horizontal left normal. Neither tilts with the cant: a tunnel wall
        (where the lamps are) stays vertical when the track in it is canted.
        """
        p = self.evaluate(chainage_m)
        lateral = np.broadcast_to(np.asarray(lateral_m, float), p.x_m.shape)
        xy = np.stack([p.x_m, p.y_m], axis=1) + lateral[:, None] * p.left_normal
        height = np.broadcast_to(np.asarray(height_m, float), p.x_m.shape)
        if self._vertical is not None:
            height = p.elevation_m + height
        return np.column_stack([xy, height])

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


def _vertical_rows(pvis):
    """Piecewise-quadratic rows (s0, z0, g0, c): z = z0 + g0·u + ½c·u², u = s − s0."""
    pvis = [tuple(map(float, p)) + (0.0,) * (3 - len(p)) for p in pvis]
    if len(pvis) < 2:
        raise ValueError('a vertical profile needs at least two PVIs')
    s = np.array([p[0] for p in pvis])
    z = np.array([p[1] for p in pvis])
    if not np.all(np.isfinite(s)) or not np.all(np.isfinite(z)) or np.any(np.diff(s) <= 0.0):
        raise ValueError('vertical profile: PVI chainages must be finite and increasing')
    g = np.diff(z) / np.diff(s)
    rows = [(s[0], z[0], g[0], 0.0)]
    last_end = s[0]
    for j in range(1, len(pvis) - 1):
        dg = g[j] - g[j - 1]
        if dg == 0.0:
            continue
        radius = pvis[j][2]
        if not np.isfinite(radius) or radius <= 0.0:
            raise ValueError(f'vertical profile: the grade change at PVI {pvis[j][:2]} needs '
                             'a vertical curve radius > 0')
        half = 0.5 * radius * abs(dg)
        begin, end = s[j] - half, s[j] + half
        if begin < last_end or end > s[j + 1]:
            raise ValueError(f'vertical profile: the vertical curve at s = {s[j]:g} m '
                             f'({begin:g}…{end:g} m) overlaps its neighbours')
        rows.append((begin, z[j] - g[j - 1] * half, g[j - 1], dg / (2.0 * half)))
        rows.append((end, z[j] + g[j] * half, g[j], 0.0))
        last_end = end
    return np.array(rows, dtype=float)


def _evaluate_vertical(rows, s):
    """Elevation (m), grade and grade rate (1/m) of the rows at chainages ``s``."""
    i = np.clip(np.searchsorted(rows[:, 0], s, side='right') - 1, 0, len(rows) - 1)
    s0, z0, g0, c = rows[i].T
    u = s - s0
    return z0 + g0 * u + 0.5 * c * u * u, g0 + c * u, c


def design_cant_m(radius_m, design_speed_mps, max_cant_m=0.120, max_deficiency_m=0.061,
                  rail_centre_distance_m=RAIL_CENTRE_DISTANCE_M, step_m=0.005):
    """Applied cant for a curve: equilibrium cant less the permitted deficiency.

    The equilibrium cant of speed v on radius R balances the centripetal acceleration,
    E = b·v²/(g·R) (11.8·V²/R mm with V in km/h on b = 1.5 m); a designer applies
    D = E − I_perm so that the fastest train runs with at most the permitted cant
    deficiency I_perm (uncompensated lateral acceleration g·I/b) and slower trains with a
    smaller excess, capped at the maximum cant and rounded up to ``step_m``. Defaults are
    metro practice on standard gauge: GB 50157-2013 (Code for Design of Metro) sets the
    cant from 11.8·V²/R with at most 120 mm, and GB 50490-2009 (Technical Code of Urban
    Rail Transit) §5.3.3 limits the uncompensated lateral acceleration in running lines
    to 0.4 m/s², i.e. 61 mm of deficiency on b = 1.5 m.

    Parameters
    ----------
    radius_m : float
        Curve radius (either sign), m.
    design_speed_mps : float
        Highest speed the curve is designed for, m/s.
    max_cant_m, max_deficiency_m, rail_centre_distance_m, step_m : float
        m.

    Returns
    -------
    float
        Cant D ≥ 0, m.
    """
    equilibrium = rail_centre_distance_m * design_speed_mps ** 2 / (_GRAVITY_MPS2
                                                                    * abs(radius_m))
    cant = float(np.clip(equilibrium - max_deficiency_m, 0.0, max_cant_m))
    return min(max_cant_m, float(np.ceil(round(cant / step_m, 9)) * step_m))


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

#: Design speed of ``curved_demo``'s curves, m/s (80 km/h: the top speed of metro stock).
DEMO_DESIGN_SPEED_MPS = 80.0 / 3.6


def _design_cants(elements, speed_mps):
    """Cant at the end of every element: :func:`design_cant_m` of the radius it reaches."""
    cants = []
    for element in elements:
        radius = float(element[2]) if element[0] != 'straight' else float('inf')
        cants.append(0.0 if not np.isfinite(radius) or radius == 0.0
                     else design_cant_m(radius, speed_mps))
    return cants


#: Cant and vertical profile of the named alignments (keyword arguments of
#: :class:`Alignment`; the horizontal geometry stays :data:`NAMED_ALIGNMENTS`').
#: ``curved_demo``: cant by :func:`design_cant_m` for 80 km/h — R = 400 m and 300 m reach
#: the 120 mm cap (4.6° of roll), R = 600 m gets 65 mm, R = 800 m 35 mm — ramped along the
#: transitions (at most 1.7 mm per metre). Vertical profile of a metro line between two
#: stations at the ends: −3 ‰ out of the station (the 3 ‰ drainage minimum in tunnels),
#: −28 ‰ down and +4 ‰, +25 ‰ up to +3 ‰ at the next station — within the 30 ‰ maximum of
#: GB 50157-2013 — joined by vertical curves of R = 5000 m (its general minimum between
#: stations; 0.1 m/s² of vertical acceleration at 80 km/h); the lowest point is 21.5 m
#: below the start.
NAMED_TRACK_PROFILES = {
    'curved_demo': dict(
        cant_m=_design_cants(NAMED_ALIGNMENTS['curved_demo'], DEMO_DESIGN_SPEED_MPS),
        vertical_profile=[(0.0, 0.0, 0.0), (250.0, -0.75, 5000.0), (1000.0, -21.75, 5000.0),
                          (1500.0, -19.75, 5000.0), (2100.0, -4.75, 5000.0),
                          (2310.0, -4.12, 0.0)]),
}
