"""Row profile → chips → packet: clock recovery, chip slicing, header search, decision.

Every function works on a batch of profiles (leading axis N) so that the same code
decodes one lamp spot per call in the tracker and 100 000 profiles per call in the fuzz
test.

Signal model (rolling shutter, ``shared/VLC_PROTOCOL.md``): image row r integrates the
lamp output over ``[t0 + r·row_time_s, t0 + r·row_time_s + exposure_s]``. After the
envelope normalisation a row reads ``y = α·c_k + (1 − α)·c_{k+1}`` where ``c`` are the
chips (0 off, 1 on) and ``α`` is the fraction of the exposure inside chip k. ``y``
crosses 0.5 when the exposure *mid-time* passes a chip boundary, which is why all times
here are exposure mid-times.
"""
import numpy as np

from vlc_common.core.protocol import (
    CRC8_TABLE,
    DATA_BITS,
    HEADER_CHIPS,
    HEADER_LEN,
    PACKET_CHIPS,
    bits_to_word,
)

# a row's vote for a chip is weighted by (fraction of its exposure inside the chip)^4:
# fully-inside rows count 1, rows straddling an edge almost nothing
OVERLAP_POWER = 4.0
HEADER_SIGNS = (2 * HEADER_CHIPS.astype(np.int8) - 1)  # +1 on, -1 off

# a chip's level must stand this many of its own noise σ from 0.5 to be read
NOISE_SIGMAS = 3.0
# fewest rows inside one chip that estimate a profile's level noise on their own
MIN_NOISE_ROWS = 4

# decision states of a folded packet chip
UNKNOWN, ON, OFF, CONFLICT = 0, 1, -1, 2

STATUS_OK = 0
STATUS_INCOMPLETE = 1      # header or some data bit not seen yet
STATUS_INCONSISTENT = 2    # Manchester violation, conflicting reads, ambiguous header
STATUS_CRC = 3             # every chip read, CRC mismatch


def find_crossings(t_s, y, w, min_weight=0.3):
    """Times where the normalised profile crosses 0.5 between adjacent valid rows.

    Parameters
    ----------
    t_s : (N, R) exposure mid-times of the rows, s (any common origin)
    y : (N, R) normalised row levels (0 off, 1 on)
    w : (N, R) row weights in [0, 1]; rows below ``min_weight`` are not used

    Returns
    -------
    tc : (N, R-1) crossing times, s (0 where there is none)
    wc : (N, R-1) crossing weights (0 where there is none)
    """
    y0, y1 = y[:, :-1], y[:, 1:]
    valid = (w[:, :-1] >= min_weight) & (w[:, 1:] >= min_weight)
    dy = y1 - y0
    cross = valid & ((y0 - 0.5) * (y1 - 0.5) < 0) & (np.abs(dy) > 1e-9)
    frac = np.where(cross, (0.5 - y0) / np.where(cross, dy, 1.0), 0.0)
    tc = np.where(cross, t_s[:, :-1] + frac * (t_s[:, 1:] - t_s[:, :-1]), 0.0)
    # a clean full swing between two rows marks an edge well; a small one weakly
    wc = np.where(cross, np.minimum(w[:, :-1], w[:, 1:]) * np.clip(np.abs(dy), 0, 1), 0.0)
    return tc, wc


def _phasors(dt, wc, rates):
    """Σ_m w·exp(2πi f dt_m) for each profile (rows) and each rate in ``rates`` (N, G)."""
    phase = (2 * np.pi) * rates[:, :, None] * dt[:, None, :]
    return (np.cos(phase) * wc[:, None, :]).sum(axis=2) + 1j * (
        np.sin(phase) * wc[:, None, :]).sum(axis=2)


def recover_clock(tc, wc, rate_hz, t_ref_s, rate_tolerance=0.0, grid=9,
                  max_crossings=48):
    """Chip-boundary phase (and optionally rate) from crossing times.

    Chip boundaries lie at ``t_b + n / f``; the phasor sum ``Σ w·exp(2πi f (t_c − t_ref))``
    points at the boundary phase, and its length measures how well one rate explains all
    crossings (timing recovery, no packet content involved). The rate search is coarse
    (``grid`` rates over ±``rate_tolerance``), then fine (five rates around the best,
    a quarter step apart), then parabolic.

    Parameters
    ----------
    tc, wc : (N, M) crossing times (s) and weights from :func:`find_crossings`
    rate_hz : (N,) or scalar, the prior chip rate, Hz
    t_ref_s : (N,) reference time (e.g. the profile's middle), s
    rate_tolerance : search the rate over ``rate_hz·(1 ± rate_tolerance)``; 0 keeps it
    max_crossings : the rate search uses at most this many strongest crossings

    Returns
    -------
    t_b : (N,) a chip-boundary time, s, the one nearest ``t_ref_s``
    f : (N,) chip rate, Hz
    strength : (N,) phasor length / total weight in [0, 1] (0 without crossings)
    """
    n = tc.shape[0]
    rate = np.broadcast_to(np.asarray(rate_hz, dtype=float), (n,))
    t_ref = np.broadcast_to(np.asarray(t_ref_s, dtype=float), (n,))
    dt = np.where(wc > 0, tc - t_ref[:, None], 0.0)
    total = wc.sum(axis=1)
    f = rate.copy()
    if rate_tolerance > 0:
        if dt.shape[1] > max_crossings:
            keep = np.argsort(-wc, axis=1)[:, :max_crossings]
            dt_s = np.take_along_axis(dt, keep, axis=1)
            wc_s = np.take_along_axis(wc, keep, axis=1)
        else:
            dt_s, wc_s = dt, wc
        step = 2 * rate_tolerance / (grid - 1)
        scales = 1.0 + np.linspace(-rate_tolerance, rate_tolerance, grid)
        mag = np.abs(_phasors(dt_s, wc_s, rate[:, None] * scales[None, :]))
        centre = scales[np.argmax(mag, axis=1)]
        fine_step = step / 4
        fine = centre[:, None] + fine_step * np.arange(-2, 3)[None, :]
        mag = np.abs(_phasors(dt_s, wc_s, rate[:, None] * fine))
        best = np.clip(np.argmax(mag, axis=1), 1, 3)
        rows = np.arange(n)
        a, b, c = mag[rows, best - 1], mag[rows, best], mag[rows, best + 1]
        denom = a - 2 * b + c
        ok = np.abs(denom) > 1e-12
        shift = np.clip(np.where(ok, 0.5 * (a - c) / np.where(ok, denom, 1.0), 0.0), -1, 1)
        f = rate * (fine[rows, best] + shift * fine_step)
    z = _phasors(dt, wc, f[:, None])[:, 0]
    strength = np.where(total > 0, np.abs(z) / np.where(total > 0, total, 1.0), 0.0)
    t_b = t_ref + np.angle(z) / (2 * np.pi * f)
    return t_b, f, strength


def slice_chips(t_s, y, w, t_b, f, exposure_s, n_chips):
    """Soft chip values of each profile on its chip grid.

    Parameters
    ----------
    t_s, y, w : (N, R) row exposure mid-times (s), normalised levels, weights
    t_b : (N,) a chip-boundary time, s; f : (N,) chip rate, Hz
    exposure_s : row exposure, s
    n_chips : K, length of the returned chip axis (enough to cover every row)

    Returns
    -------
    n0 : (N,) int64 index (chips since ``t_b``) of chip 0 of the returned axis
    value : (N, K) weighted mean level of the rows covering each chip (0.5 if none)
    weight : (N, K) Σ row weight · overlap^4: the number of fully-inside rows' worth of
        evidence behind each value
    """
    n, r = y.shape
    x = (t_s - t_b[:, None]) * f[:, None]                         # chip coordinate
    half = 0.5 * exposure_s * f[:, None]                          # half exposure, chips
    usable = w > 0
    x_min = np.where(usable, x - half, np.inf).min(axis=1)
    n0 = np.floor(np.where(np.isfinite(x_min), x_min, 0.0)).astype(np.int64)
    kc = np.floor(x).astype(np.int64)
    lo, hi = x - half, x + half
    span = 2 * half
    alpha_c = (np.minimum(hi, kc + 1) - np.maximum(lo, kc)) / span
    alpha_l = np.clip(kc - lo, 0, None) / span
    alpha_r = np.clip(hi - (kc + 1), 0, None) / span
    total_v = np.zeros(n * n_chips)
    total_w = np.zeros(n * n_chips)
    base = (np.arange(n) * n_chips)[:, None]
    for dk, alpha in ((0, alpha_c), (-1, alpha_l), (1, alpha_r)):
        k = kc + dk - n0[:, None]
        ok = usable & (alpha > 0) & (k >= 0) & (k < n_chips)
        wt = np.where(ok, w * alpha ** OVERLAP_POWER, 0.0)
        idx = np.where(ok, base + k, 0).ravel()
        total_w += np.bincount(idx, weights=wt.ravel(), minlength=n * n_chips)
        total_v += np.bincount(idx, weights=(wt * y).ravel(), minlength=n * n_chips)
    total_w = total_w.reshape(n, n_chips)
    total_v = total_v.reshape(n, n_chips)
    value = np.where(total_w > 0, total_v / np.where(total_w > 0, total_w, 1.0), 0.5)
    return n0, value, total_w


def level_noise(t_s, y, w, t_b, f, exposure_s):
    """Robust σ of the normalised row levels of each profile (N,).

    Rows whose exposure lies (almost) entirely inside one chip of the grid should read
    0 or 1: their distances to the nearer of the two give σ by the MAD. With fewer than
    ``MIN_NOISE_ROWS`` such rows every usable row is used, which overstates σ (rows
    across a chip edge read in between): on the safe side.
    """
    x = (t_s - t_b[:, None]) * f[:, None]
    half = 0.5 * exposure_s * f[:, None]
    kc = np.floor(x)
    alpha = (np.minimum(x + half, kc + 1) - np.maximum(x - half, kc)) / (2 * half)
    usable = w >= 0.5
    dist = np.abs(y - np.clip(np.round(y), 0.0, 1.0))
    inside = usable & (alpha >= 0.9)
    use = np.where((inside.sum(axis=1) >= MIN_NOISE_ROWS)[:, None], inside, usable)
    count = use.sum(axis=1)
    if dist.shape[1] == 0:
        return np.full(len(y), 0.5)
    ordered = np.sort(np.where(use, dist, np.inf), axis=1)
    rows = np.arange(len(y))
    upper = ordered[rows, np.maximum(count // 2, 0)]
    lower = ordered[rows, np.maximum((count - 1) // 2, 0)]
    # no usable row: no evidence of a clean profile, so a large σ
    return np.where(count > 0, 1.4826 * 0.5 * (upper + lower), 0.5)


def chip_states(value, weight, margin, min_weight, sigma=None):
    """Hard reads: ON (+1), OFF (−1) or UNKNOWN (0) per chip (same shape as ``value``).

    A chip is read when rows worth ``min_weight`` fully-inside exposures cover it and
    its level is ``margin`` from 0.5, or ``NOISE_SIGMAS`` times its own noise
    (``sigma`` (N,), the profile's row noise, over √weight) when that is larger: a
    noisy profile reads only the chips its noise cannot have flipped.
    """
    seen = weight >= min_weight
    if sigma is not None:
        margin = np.maximum(margin, NOISE_SIGMAS * np.asarray(sigma, float)[:, None]
                            / np.sqrt(np.maximum(weight, min_weight)))
    on = seen & (value >= 0.5 + margin)
    off = seen & (value <= 0.5 - margin)
    return np.where(on, ON, np.where(off, OFF, UNKNOWN)).astype(np.int8)


def header_positions(states):
    """(N, K-5) bool: the six chips starting here read ``111000`` outright."""
    if states.shape[1] < HEADER_LEN:
        return np.zeros((states.shape[0], 0), dtype=bool)
    windows = np.lib.stride_tricks.sliding_window_view(states, HEADER_LEN, axis=1)
    return np.all(windows == HEADER_SIGNS, axis=2)


def fold_votes(states, value, weight, shift, valid=None):
    """Fold chip reads into the 54 packet chips given each chip's packet position.

    Parameters
    ----------
    states, value, weight : (N, K) chip reads and soft values of fragments
    shift : (N,) packet chip index of chip 0 of each row of the arrays
    valid : optional (N, K) bool mask of chips to use

    Returns
    -------
    n_on, n_off : (N, 54) counts of ON / OFF reads per packet chip
    sum_vw, sum_w : (N, 54) pooled soft evidence per packet chip
    """
    n, k = states.shape
    pos = (np.arange(k)[None, :] + np.asarray(shift)[:, None]) % PACKET_CHIPS
    idx = (np.arange(n)[:, None] * PACKET_CHIPS + pos)
    use = np.ones_like(states, dtype=bool) if valid is None else valid
    size = n * PACKET_CHIPS
    n_on = np.bincount(idx[use & (states == ON)], minlength=size).reshape(n, -1)
    n_off = np.bincount(idx[use & (states == OFF)], minlength=size).reshape(n, -1)
    sum_w = np.bincount(idx[use], weights=weight[use], minlength=size).reshape(n, -1)
    sum_vw = np.bincount(idx[use], weights=(value * weight)[use],
                         minlength=size).reshape(n, -1)
    return n_on, n_off, sum_vw, sum_w


def packet_states(n_on, n_off, sum_vw, sum_w, margin, min_weight, sigma=None):
    """Per packet chip: ON / OFF / UNKNOWN / CONFLICT from folded reads.

    A chip read by fragments is decided by a clear majority (winners ≥ 1 + 2·losers,
    else CONFLICT); a chip no fragment read outright falls back on the pooled soft
    evidence of all its rows (held to the noise margin of ``sigma`` (N,), see
    :func:`chip_states`).
    """
    major_on = n_on >= 1 + 2 * n_off
    major_off = n_off >= 1 + 2 * n_on
    read = (n_on + n_off) > 0
    pooled = np.where(sum_w > 0, sum_vw / np.where(sum_w > 0, sum_w, 1.0), 0.5)
    soft = chip_states(pooled, sum_w, margin, min_weight, sigma)
    return np.where(read, np.where(major_on, ON, np.where(major_off, OFF, CONFLICT)),
                    soft).astype(np.int8)


# The packet start must be told apart from every other fold index by at least this many
# contradicting reads: one misread chip can neither hide the true start nor reveal a
# false one.
MIN_CONTRADICTIONS = 2

# (54, 54): row o lists the packet chips in order for a packet starting at fold index o
_ROTATIONS = (np.arange(PACKET_CHIPS)[:, None] + np.arange(PACKET_CHIPS)[None, :]) \
    % PACKET_CHIPS


def origin_contradictions(states):
    """(N, 54) int: reads that contradict a packet starting at each fold index.

    A read contradicts a start where a chip read there contradicts the header
    ``111000``, or where a data chip pair read in full is not Manchester (``00`` or
    ``11``). Runs of three equal chips exist only in the header and Manchester pairs
    only line up at even offsets from it, so with enough chips read every fold index but
    the true start collects contradictions: the header is located by the protocol's
    structure, not by a CRC.
    """
    rolled = states[:, _ROTATIONS]                                    # (N, 54, 54)
    head = rolled[:, :, :HEADER_LEN]
    against_header = np.count_nonzero(head == -HEADER_SIGNS, axis=2)
    data = rolled[:, :, HEADER_LEN:].reshape(states.shape[0], PACKET_CHIPS, DATA_BITS, 2)
    a, b = data[..., 0], data[..., 1]
    violations = np.count_nonzero(((a == ON) | (a == OFF)) & (a == b), axis=2)
    return against_header + violations


def known_bits(states):
    """The data word as read so far from packets whose header sits at chip 0.

    A bit is known when one of its chips is read, neither is in conflict and a fully
    read pair is Manchester. Returns word (N,) int64 (24 bits, MSB first: UID << 8 |
    CRC, unknown bits 0) and mask (N,) int64 (1 where the bit is known).
    """
    n = states.shape[0]
    data = states[:, HEADER_LEN:].reshape(n, DATA_BITS, 2)
    a, b = data[:, :, 0], data[:, :, 1]
    a_known = (a == ON) | (a == OFF)
    b_known = (b == ON) | (b == OFF)
    bad = (a == CONFLICT) | (b == CONFLICT) | (a_known & b_known & (a == b))
    known = (a_known | b_known) & ~bad
    bits = np.where(a_known, a == ON, b == OFF) & known
    weights = np.int64(1) << np.arange(DATA_BITS - 1, -1, -1, dtype=np.int64)
    return (bits * weights).sum(axis=1), (known * weights).sum(axis=1)


def decide_packets(states):
    """Decode folded packets whose header sits at packet chip 0.

    Parameters
    ----------
    states : (N, 54) ON/OFF/UNKNOWN/CONFLICT per packet chip, header first

    Returns
    -------
    uid : (N,) int64, the UID where status is STATUS_OK, else −1
    status : (N,) int8 (STATUS_*)
    bits_known : (N,) number of the 24 data bits read
    """
    n = states.shape[0]
    header = states[:, :HEADER_LEN]
    header_bad = np.any((header == -HEADER_SIGNS) | (header == CONFLICT), axis=1)
    data = states[:, HEADER_LEN:].reshape(n, DATA_BITS, 2)
    a, b = data[:, :, 0], data[:, :, 1]
    a_known = (a == ON) | (a == OFF)
    b_known = (b == ON) | (b == OFF)
    conflict = (a == CONFLICT) | (b == CONFLICT)
    violation = a_known & b_known & (a == b)
    bit_known = (a_known | b_known) & ~conflict & ~violation
    bits = np.where(a_known, a == ON, b == OFF).astype(np.int64)
    bits_known = bit_known.sum(axis=1)
    uid, crc = bits_to_word(bits)
    crc_ok = CRC8_TABLE[(CRC8_TABLE[(uid >> 8) & 0xFF] ^ (uid & 0xFF))] == crc
    inconsistent = header_bad | np.any(violation | conflict, axis=1)
    complete = bits_known == DATA_BITS
    status = np.full(n, STATUS_INCOMPLETE, dtype=np.int8)
    status[inconsistent] = STATUS_INCONSISTENT
    status[complete & ~inconsistent & ~crc_ok] = STATUS_CRC
    ok = complete & ~inconsistent & crc_ok
    status[ok] = STATUS_OK
    return np.where(ok, uid, -1), status, bits_known


def decide_fold(states, chunk=4096):
    """Locate the packet start in folded chips (arbitrary origin) and decode there.

    The start is the one fold index without contradicting reads
    (:func:`origin_contradictions`), provided every other index has at least
    ``MIN_CONTRADICTIONS``; with none left the reads are inconsistent, otherwise the
    packet is not located yet.

    Parameters
    ----------
    states : (N, 54) ON/OFF/UNKNOWN/CONFLICT per fold index

    Returns
    -------
    uid (N,) int64 (−1 unless STATUS_OK), status (N,) int8, bits_known (N,),
    origin (N,) fold index of the packet start (−1 where not located)
    """
    n = states.shape[0]
    uid = np.full(n, -1, dtype=np.int64)
    status = np.full(n, STATUS_INCOMPLETE, dtype=np.int8)
    bits_known = np.zeros(n, dtype=np.int64)
    origin = np.full(n, -1, dtype=np.int64)
    for lo in range(0, n, chunk):
        part = states[lo:lo + chunk]
        against = origin_contradictions(part)
        open_ = against == 0
        count = open_.sum(axis=1)
        first = np.argmax(open_, axis=1)
        runner_up = np.sort(against, axis=1)[:, 1]
        located = (count == 1) & (runner_up >= MIN_CONTRADICTIONS)
        status[lo:lo + chunk] = np.where(count == 0, STATUS_INCONSISTENT, STATUS_INCOMPLETE)
        idx = np.flatnonzero(located)
        if len(idx):
            rows = part[idx][np.arange(len(idx))[:, None], _ROTATIONS[first[idx]]]
            u, st, bk = decide_packets(rows)
            uid[lo + idx], status[lo + idx], bits_known[lo + idx] = u, st, bk
            origin[lo + idx] = first[idx]
    return uid, status, bits_known, origin


def profile_chip_count(n_rows, cfg):
    """Length of the chip axis that covers ``n_rows`` rows at the fastest searched rate."""
    f_max = cfg.chip_rate_hz * (1 + cfg.rate_search_tolerance)
    return int(np.ceil((n_rows * cfg.row_time_s + cfg.exposure_s) * f_max)) + 4


def read_profiles(t_s, y, w, cfg, rate_hz=None, search_rate=None):
    """Clock recovery and chip slicing of a batch of row profiles.

    Parameters
    ----------
    t_s, y, w : (N, R) exposure mid-times (s), normalised levels, weights
    cfg : DecoderConfig
    rate_hz : (N,) prior chip rates (default the nominal rate)
    search_rate : search the rate within ±rate_search_tolerance; default: only for
        profiles spanning at least ``rate_search_min_chips`` chips (shorter ones cannot
        resolve a 2 % mismatch, which moves their end chips by < 0.3 chip anyway)

    Returns
    -------
    dict with t_b (N,), f (N,), strength (N,), n0 (N,), value/weight/states (N, K),
    sigma (N,) the row level noise (:func:`level_noise`)
    """
    n, r = y.shape
    rate = np.full(n, cfg.chip_rate_hz) if rate_hz is None else np.asarray(rate_hz, float)
    tc, wc = find_crossings(t_s, y, w)
    usable = w > 0
    t_first = np.where(usable, t_s, np.inf).min(axis=1)
    t_last = np.where(usable, t_s, -np.inf).max(axis=1)
    has_rows = np.isfinite(t_first)
    t_first = np.where(has_rows, t_first, 0.0)
    t_last = np.where(has_rows, t_last, 0.0)
    t_mid = 0.5 * (t_first + t_last)
    if search_rate is None:
        span_chips = (t_last - t_first) * rate
        search = span_chips >= cfg.rate_search_min_chips
    else:
        search = np.full(n, bool(search_rate))
    t_b, f, strength = recover_clock(tc, wc, rate, t_mid)
    if np.any(search):
        sel = np.flatnonzero(search)
        t_b[sel], f[sel], strength[sel] = recover_clock(
            tc[sel], wc[sel], rate[sel], t_mid[sel], cfg.rate_search_tolerance)
    k = profile_chip_count(r, cfg)
    n0, value, weight = slice_chips(t_s, y, w, t_b, f, cfg.exposure_s, k)
    sigma = level_noise(t_s, y, w, t_b, f, cfg.exposure_s)
    states = chip_states(value, weight, cfg.chip_margin, cfg.min_chip_weight, sigma)
    return {'t_b': t_b, 'f': f, 'strength': strength, 'n0': n0, 'value': value,
            'weight': weight, 'states': states, 'sigma': sigma}


def decode_profiles(t_s, y, w, cfg, search_rate=None):
    """Decode each profile on its own: every chip of the packet must lie within it.

    The profile's chips are folded modulo 54 (so a profile holding more than one packet
    must agree with itself), the packet start is located by the protocol's structure
    (:func:`decide_fold`) and every header the profile shows outright must sit there.
    One CRC check per profile, at the position the structure dictates: no phase is ever
    tried against the CRC.

    Returns
    -------
    uid : (N,) int64 (−1 where nothing was accepted); status : (N,) int8
    """
    read = read_profiles(t_s, y, w, cfg, search_rate=search_rate)
    states = read['states']
    n_on, n_off, sum_vw, sum_w = fold_votes(states, read['value'], read['weight'],
                                            read['n0'] % PACKET_CHIPS)
    folded = packet_states(n_on, n_off, sum_vw, sum_w, cfg.chip_margin,
                           cfg.min_chip_weight, read['sigma'])
    uid, status, _, origin = decide_fold(folded)
    heads = header_positions(states)
    k = heads.shape[1]
    pos = (np.arange(k)[None, :] + read['n0'][:, None]) % PACKET_CHIPS
    stray = np.any(heads & (pos != origin[:, None]), axis=1) & (origin >= 0)
    status = np.where(stray, STATUS_INCONSISTENT, status).astype(np.int8)
    uid = np.where(status == STATUS_OK, uid, -1)
    return uid, status
