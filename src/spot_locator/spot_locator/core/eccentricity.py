"""Perspective eccentricity of the lamp disc: the imaged ellipse's centre is not the image
of the disc centre, and the offset differs between the two cameras.

For a disc of radius R, centre C = (X, Y, Z) and unit normal n in an optical frame, the
image conic's centre is the pole of the line at infinity, ``e ~ K (R²(I − n nᵀ) − C Cᵀ) ẑ``,
which gives the exact offset from the projected centre c = (fx X/Z + cx, fy Y/Z + cy)::

    e_u − c_u = fx R² (Z n_x n_z + X (1 − n_z²)) / (Z (Z² − R² (1 − n_z²)))
    e_v − c_v = fy R² (Z n_y n_z + Y (1 − n_z²)) / (Z (Z² − R² (1 − n_z²)))

(the classic bias of circular calibration targets, cf. Heikkilä 2000, Ahn 1999). The
right camera sees the same disc at X − b, so the disparity is biased by about
``fx R² b (1 − n_z²) / Z³``.

Correction: triangulate the lamp from the two ellipse centres, compute both offsets from
the disc geometry (normal and radius from the lamp map or the nominal lamp), subtract,
re-triangulate, repeat (converges in 2–3 steps because the offset varies slowly with
depth). The disc normal in the camera frame comes either from the nominal mounting or,
for spots large enough, from the fitted ellipse itself (:func:`normals_from_conic`),
which follows the platform's attitude disturbances.
"""
import numpy as np


def ellipse_centre_offset(centre_cam, normal_cam, radius_m, fx, fy):
    """Offset (Δu, Δv) = ellipse centre − projected disc centre, pixels.

    Parameters
    ----------
    centre_cam : (..., 3) disc centres in the optical frame (m).
    normal_cam : (3,) or (..., 3) unit disc normals in the optical frame.
    radius_m : disc radius (m).
    fx, fy : focal lengths (px).

    Returns
    -------
    (..., 2) offsets in pixels.
    """
    C = np.asarray(centre_cam, float)
    n = np.asarray(normal_cam, float)
    X, Y, Z = C[..., 0], C[..., 1], C[..., 2]
    nz = n[..., 2]
    s2 = 1.0 - nz ** 2
    den = Z * (Z ** 2 - radius_m ** 2 * s2)
    du = fx * radius_m ** 2 * (Z * n[..., 0] * nz + X * s2) / den
    dv = fy * radius_m ** 2 * (Z * n[..., 1] * nz + Y * s2) / den
    return np.stack([du, dv], axis=-1)


def triangulate(uv_left, uv_right, fx, fy, cx, cy, baseline_m):
    """Rectified-stereo triangulation (paper eq. 12–14) in the left optical frame.

    ``uv_left``, ``uv_right`` (..., 2) px → (..., 3) metres; Z = fx b / (u_l − u_r); the
    row is the mean of both images' rows.
    """
    uvl = np.asarray(uv_left, float)
    uvr = np.asarray(uv_right, float)
    d = uvl[..., 0] - uvr[..., 0]
    Z = fx * baseline_m / d
    X = (uvl[..., 0] - cx) * Z / fx
    Y = (0.5 * (uvl[..., 1] + uvr[..., 1]) - cy) * Z / fy
    return np.stack([X, Y, Z], axis=-1)


def correct_pair(uv_left, uv_right, normal_cam, radius_m, fx, fy, cx, cy, baseline_m,
                 iterations=3):
    """Remove the eccentricity offset from one stereo pair of ellipse centres.

    Parameters
    ----------
    uv_left, uv_right : (2,) ellipse centres (px).
    normal_cam : (3,) disc normal in the (left = right) optical frame.
    radius_m : disc radius (m).
    fx, fy, cx, cy, baseline_m : rectified stereo geometry.
    iterations : fixed-point steps.

    Returns
    -------
    (uv_left_corrected, uv_right_corrected, offset_left, offset_right), each (2,) px:
    the estimated projections of the disc centre and the offsets that were removed.
    """
    e_l = np.asarray(uv_left, float)
    e_r = np.asarray(uv_right, float)
    off_l = np.zeros(2)
    off_r = np.zeros(2)
    for _ in range(iterations):
        P = triangulate(e_l - off_l, e_r - off_r, fx, fy, cx, cy, baseline_m)
        if not np.isfinite(P).all() or P[2] <= radius_m:
            return e_l, e_r, np.zeros(2), np.zeros(2)
        off_l = ellipse_centre_offset(P, normal_cam, radius_m, fx, fy)
        off_r = ellipse_centre_offset(P - np.array([baseline_m, 0.0, 0.0]), normal_cam,
                                      radius_m, fx, fy)
    return e_l - off_l, e_r - off_r, off_l, off_r


def normals_from_conic(Q, K):
    """The two disc-plane normals (2, 3) consistent with an imaged circle.

    ``Q`` (3, 3) is the ellipse in pixel coordinates, ``K`` the camera matrix. The cone
    through the camera centre and the ellipse, ``A = Kᵀ Q K``, has eigenvalues
    λ1 ≥ λ2 > 0 > λ3 (after fixing the sign); the circle's plane normal is
    ``±sqrt((λ1 − λ2)/(λ1 − λ3)) e1 + sqrt((λ2 − λ3)/(λ1 − λ3)) e3`` (Shiu & Ahmad 1989).
    The normals returned point toward the camera (n_z < 0).
    """
    A = K.T @ Q @ K
    A = 0.5 * (A + A.T)
    lam, V = np.linalg.eigh(A)
    if (lam > 0).sum() == 1:
        lam = -lam
    order = np.argsort(lam)[::-1]
    lam, V = lam[order], V[:, order]
    l1, l2, l3 = lam
    if not (l1 >= l2 > 0 > l3):
        return np.zeros((0, 3))
    a = np.sqrt(max((l1 - l2) / (l1 - l3), 0.0))
    c = np.sqrt(max((l2 - l3) / (l1 - l3), 0.0))
    out = []
    for s in (1.0, -1.0):
        n = V @ np.array([s * a, 0.0, c])
        n /= np.linalg.norm(n)
        out.append(-n if n[2] > 0 else n)
    return np.array(out)


def pick_normal(candidates, nominal, max_angle_deg):
    """The candidate closest to ``nominal`` if within ``max_angle_deg``, else None."""
    if len(candidates) == 0:
        return None
    nominal = np.asarray(nominal, float) / np.linalg.norm(nominal)
    cosines = candidates @ nominal
    i = int(np.argmax(cosines))
    if cosines[i] < np.cos(np.radians(max_angle_deg)):
        return None
    return candidates[i]


def angle_deg(a, b):
    """Angle between two vectors, degrees."""
    a = np.asarray(a, float)
    b = np.asarray(b, float)
    c = np.dot(a, b) / (np.linalg.norm(a) * np.linalg.norm(b))
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


def _disc_chords(K, P0, V, t, normal, radius_m, rows):
    """Chord midpoint (px) and squared half-width (px²) of a moving disc on image rows.

    The disc's centre is ``P0 + V t[i]`` (optical frame, m) when row ``rows[i]`` is read.
    A ray X meets the disc plane at λX with λ = (n·C)/(n·X); it grazes the rim when
    |(n·C) X − (n·X) C|² = R² (n·X)², a quadratic form Xᵀ A X with
    A = s² I − s (n Cᵀ + C nᵀ) + (|C|² − R²) n nᵀ, s = n·C. With C linear in t every
    entry of A is a quadratic in t. On row v the normalised ray is X = (x, y, 1),
    y = (v − cy)/fy, and the chord's ends are the roots in x of
    A00 x² + 2 (A01 y + A02) x + A11 y² + 2 A12 y + A22 = 0.
    """
    n = np.asarray(normal, float).tolist()
    p = np.asarray(P0, float).tolist()
    v = np.asarray(V, float).tolist()
    s0 = n[0] * p[0] + n[1] * p[1] + n[2] * p[2]          # s = s0 + s1 t
    s1 = n[0] * v[0] + n[1] * v[1] + n[2] * v[2]
    q0 = p[0] * p[0] + p[1] * p[1] + p[2] * p[2] - radius_m ** 2   # |C|² − R²
    q1 = 2.0 * (p[0] * v[0] + p[1] * v[1] + p[2] * v[2])
    q2 = v[0] * v[0] + v[1] * v[1] + v[2] * v[2]

    def entry(i, j):
        """(1, t, t²) coefficients of A_ij."""
        u0, u1 = n[i] * p[j] + p[i] * n[j], n[i] * v[j] + v[i] * n[j]
        nn = n[i] * n[j]
        d = 1.0 if i == j else 0.0
        return (d * s0 * s0 - s0 * u0 + q0 * nn,
                2.0 * d * s0 * s1 - s0 * u1 - s1 * u0 + q1 * nn,
                d * s1 * s1 - s1 * u1 + q2 * nn)

    t = np.asarray(t, float)
    t2 = t * t
    a00, a01, a02, a11, a12, a22 = (c0 + c1 * t + c2 * t2 for c0, c1, c2 in (
        entry(0, 0), entry(0, 1), entry(0, 2), entry(1, 1), entry(1, 2), entry(2, 2)))
    fx, fy, cx, cy = float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2])
    y = (np.asarray(rows, float) - cy) / fy
    xm = -(a01 * y + a02) / a00
    w2 = xm * xm - ((a11 * y + 2.0 * a12) * y + a22) / a00
    return cx + fx * xm, fx * fx * w2


def _line_and_parabola(r, m, w2):
    """Least-squares m = a + k r and w2 = g0 + g1 r + g2 r² (r centred by the caller)."""
    r2 = r * r
    n, s1, s2 = float(len(r)), float(r.sum()), float(r2.sum())
    s3, s4 = float(r2 @ r), float(r2 @ r2)
    sm, srm = float(m.sum()), float(r @ m)
    det = n * s2 - s1 * s1
    a, k = (s2 * sm - s1 * srm) / det, (n * srm - s1 * sm) / det
    # the parabola's normal equations by Cramer's rule (g1, g2 only)
    t0, t1, t2 = float(w2.sum()), float(r @ w2), float(r2 @ w2)
    c00, c01, c02 = s2 * s4 - s3 * s3, s2 * s3 - s1 * s4, s1 * s3 - s2 * s2
    c11, c12, c22 = n * s4 - s2 * s2, s1 * s2 - n * s3, n * s2 - s1 * s1
    det3 = n * c00 + s1 * c01 + s2 * c02
    g1 = (c01 * t0 + c11 * t1 + c12 * t2) / det3
    g2 = (c02 * t0 + c12 * t1 + c22 * t2) / det3
    return a, k, g1, g2


def rolling_shutter_offset(P0, velocity, normal, radius_m, K, row_time_s, exposure_s):
    """Offset of the chord-fit centre of a moving disc from its true projection.

    The lamp centre is at ``P0 + velocity·t`` (optical frame, t since the image stamp).
    Row r shows the disc as it was at ``t_r = r·row_time_s + exposure_s/2``. The chord
    midpoints and half-widths of those per-row ellipses are fitted with a line and a
    parabola, exactly as :func:`~.centres.chord_fit` does with the image, giving the
    centre the fit will report; the truth is the projection of the centre at the
    exposure mid-time of its own row (fixed point). Returns ``(offset (2,), v_true)``;
    with zero velocity the offset equals :func:`ellipse_centre_offset`.
    """
    (offset,), v = _rolling_shutter_offsets(P0, (0.0,), velocity, normal, radius_m, K,
                                            row_time_s, exposure_s)
    return offset, v


def _rolling_shutter_offsets(P0, shifts_x, velocity, normal, radius_m, K, row_time_s,
                             exposure_s):
    """:func:`rolling_shutter_offset` of the disc at ``P0 − (s, 0, 0)`` for each s in
    ``shifts_x`` (the cameras of a rectified rig: the same rows, the same instants).

    Returns the list of offsets (2,) and the truth row (the same for every shift: it
    depends on the centre's y and z only).
    """
    P0 = np.asarray(P0, float)
    V = np.asarray(velocity, float)
    fx, fy, cx, cy = float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2])
    (x0, y0, z0), (vx, vy, vz) = P0.tolist(), V.tolist()
    v = cy
    for _ in range(5):    # truth row: a contraction (the image moves ≪ 1 row per row)
        t = v * row_time_s + 0.5 * exposure_s
        y, z = y0 + vy * t, z0 + vz * t
        v = fy * y / z + cy
    # rows the moving disc may cover: the disc's largest half-height fy·R/Z, with margin
    # for the motion during the readout; rows the ellipse misses drop out below
    half_h = 1.3 * fy * radius_m / z + 3.0
    rows = np.arange(np.floor(v - half_h), np.ceil(v + half_h) + 1)
    t_rows = rows * row_time_s + 0.5 * exposure_s
    offsets = []
    for shift in shifts_x:
        x = (x0 - shift) + vx * t
        truth = np.array([fx * x / z + cx, v])
        m, w2 = _disc_chords(K, (x0 - shift, y0, z0), V, t_rows, normal, radius_m, rows)
        inside = w2 > 0.0
        if np.count_nonzero(inside) < 5:
            offsets.append(np.zeros(2))
            continue
        r, m, w2 = rows[inside], m[inside], w2[inside]
        rbar = float(r.sum()) / len(r)
        a, k, g1, g2 = _line_and_parabola(r - rbar, m, w2)
        d0 = -g1 / (2.0 * g2)
        observed = np.array([a + k * d0, rbar + d0])
        offsets.append(observed - truth)
    return offsets, v


def correct_pair_moving(uv_left, uv_right, velocity, normal_cam, radius_m, K, baseline_m,
                        row_time_s, exposure_s, iterations=2):
    """:func:`correct_pair` for a moving lamp: eccentricity and rolling-shutter model.

    ``velocity`` (3,) m/s is the lamp's velocity relative to the cameras in the optical
    frame. Returns the estimated projections of the disc centre at the exposure mid-time
    of their row (left, right), the offsets removed, and that row.
    """
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    e_l = np.asarray(uv_left, float)
    e_r = np.asarray(uv_right, float)
    V = np.asarray(velocity, float)
    off_l = off_r = np.zeros(2)
    v_true = e_l[1]
    for _ in range(iterations):
        c_l, c_r = e_l - off_l, e_r - off_r
        P = triangulate(c_l, c_r, fx, fy, cx, cy, baseline_m)
        if not np.isfinite(P).all() or P[2] <= radius_m:
            return e_l, e_r, np.zeros(2), np.zeros(2), e_l[1]
        P0 = P - V * (0.5 * (c_l[1] + c_r[1]) * row_time_s + 0.5 * exposure_s)
        (off_l, off_r), v_true = _rolling_shutter_offsets(
            P0, (0.0, baseline_m), V, normal_cam, radius_m, K, row_time_s, exposure_s)
    return e_l - off_l, e_r - off_r, off_l, off_r, v_true
