"""Synthetic lamp signals written from ``shared/VLC_PROTOCOL.md`` for tests and benchmarks.

Independent of the rig's transmitter model (``vlc_stereo_camera.core.transmitter``), so
that decoder and rig are checked against the protocol text, not against each other.
Nothing here is used by the decoding itself; the node's warm-up
(``vlc_decoder_node.warm_up``) decodes a few frames of ``render_stereo``.
"""
from dataclasses import dataclass

import numpy as np

from vlc_common.core.protocol import PACKET_CHIPS, packet_chips


@dataclass
class LampSignal:
    """Light output of one lamp: packets of ``uid`` back to back.

    Chip k of the packet starting at ``phase_s`` lasts
    ``[phase_s + k/chip_rate_hz, phase_s + (k+1)/chip_rate_hz)``; its level is 1 when
    on and ``off_level`` when off. ``chips`` overrides the packet (e.g. corrupted ones).
    """

    uid: int
    chip_rate_hz: float = 10_000.0
    phase_s: float = 0.0
    off_level: float = 0.05
    chips: np.ndarray = None

    def __post_init__(self):
        if self.chips is None:
            self.chips = packet_chips(self.uid)
        self.chips = np.asarray(self.chips, dtype=float)
        self.levels = self.off_level + (1.0 - self.off_level) * self.chips
        self.cum = np.concatenate([[0.0], np.cumsum(self.levels)])

    def _integral(self, t_s):
        """∫ level dt from the packet start to ``t_s``, in chip durations."""
        x = (np.asarray(t_s, dtype=float) - self.phase_s) * self.chip_rate_hz
        period = len(self.levels)
        whole = np.floor(x / period)
        rem = x - whole * period
        k = np.minimum(np.floor(rem).astype(np.int64), period - 1)
        return whole * self.cum[-1] + self.cum[k] + (rem - k) * self.levels[k]

    def mean_over(self, t_start_s, t_end_s):
        """Mean level over exposure windows (arrays of s), exactly."""
        t_start_s = np.asarray(t_start_s, dtype=float)
        t_end_s = np.asarray(t_end_s, dtype=float)
        return (self._integral(t_end_s) - self._integral(t_start_s)) / (
            (t_end_s - t_start_s) * self.chip_rate_hz)


def row_levels(signal, t0_s, n_rows, row_time_s=30e-6, exposure_s=50e-6, first_row=0):
    """Lamp level seen by rows ``first_row .. first_row + n_rows − 1`` of a frame at t0."""
    start = t0_s + (first_row + np.arange(n_rows)) * row_time_s
    return signal.mean_over(start, start + exposure_s)


def worked_example_uid():
    """The protocol's worked example: line_id 1, lamp_id 42 → UID 0x102A."""
    return (1 << 12) | 42


def spot_patch(levels, width_px, height_px, gain_dn=200.0, psf_sigma_px=0.7,
               background_dn=4.0, noise_dn=1.5, shot=True, rng=None, margin_px=6,
               saturation_dn=255.0, centre_offset=(0.0, 0.0)):
    """Image patch of one elliptic lamp spot whose rows carry ``levels``.

    Parameters
    ----------
    levels : (H,) lamp level of each patch row (from :func:`row_levels`), H ≥ height
    width_px, height_px : full axes of the spot ellipse, px
    gain_dn : digital number of a fully lit pixel when the lamp is on
    psf_sigma_px : Gaussian optical blur, px
    background_dn, noise_dn : dark level and read noise (DN); ``shot`` adds Poisson-like
        noise of variance = signal (DN)
    centre_offset : (du, dv) sub-pixel offset of the ellipse centre from the patch centre

    Returns
    -------
    patch : (H, W) float image (not yet quantised); ellipse centre (u, v) in the patch
    """
    rng = np.random.default_rng() if rng is None else rng
    n_rows = len(levels)
    n_cols = int(np.ceil(width_px)) + 2 * margin_px
    uc = 0.5 * (n_cols - 1) + centre_offset[0]
    vc = 0.5 * (n_rows - 1) + centre_offset[1]
    # coverage by 4×4 supersampling (the lamp disc seen obliquely is an ellipse)
    ss = 4
    offs = (np.arange(ss) + 0.5) / ss - 0.5
    vv = np.arange(n_rows)[:, None, None, None] + offs[None, None, :, None]
    uu = np.arange(n_cols)[None, :, None, None] + offs[None, None, None, :]
    inside = ((uu - uc) / (0.5 * width_px)) ** 2 + ((vv - vc) / (0.5 * height_px)) ** 2 <= 1
    coverage = inside.mean(axis=(2, 3))
    if psf_sigma_px > 0:
        radius = int(np.ceil(3 * psf_sigma_px))
        k = np.exp(-0.5 * (np.arange(-radius, radius + 1) / psf_sigma_px) ** 2)
        k /= k.sum()
    else:
        k = np.ones(1)
    # the lens spreads the light the instant it arrives, and each sensor row integrates
    # what reaches it during its own exposure: blur the disc, then modulate the rows
    img = coverage * gain_dn
    img = np.apply_along_axis(lambda c: np.convolve(c, k, mode='same'), 0, img)
    img = np.apply_along_axis(lambda r: np.convolve(r, k, mode='same'), 1, img)
    img = img * np.asarray(levels)[:, None]
    img = img + background_dn
    if shot:
        img = img + rng.normal(size=img.shape) * np.sqrt(np.maximum(img, 0.0))
    img = img + rng.normal(size=img.shape) * noise_dn
    return np.clip(img, 0, saturation_dn), (uc, vc)


def paste(image, patch, top, left):
    """Add ``patch`` into ``image`` (uint8 or float) at (top, left), clipped to the image."""
    h, w = patch.shape
    r0, c0 = max(top, 0), max(left, 0)
    r1, c1 = min(top + h, image.shape[0]), min(left + w, image.shape[1])
    if r1 <= r0 or c1 <= c0:
        return image
    sub = patch[r0 - top:r1 - top, c0 - left:c1 - left]
    image[r0:r1, c0:c1] = np.maximum(image[r0:r1, c0:c1], sub)
    return image


@dataclass
class SyntheticLamp:
    """A lamp spot in a synthetic stereo frame: image placement and signal."""

    signal: LampSignal
    u_left: float
    v: float
    disparity_px: float
    width_px: float
    height_px: float


def render_stereo(lamps, t0_s, width=1280, height=720, row_time_s=30e-6,
                  exposure_s=50e-6, background_dn=4.0, noise_dn=1.5, gain_dn=200.0,
                  psf_sigma_px=0.7, rng=None):
    """A synthetic mono8 stereo pair with the given lamp spots (rectified: same rows).

    Returns (left, right) uint8 images of shape (height, width).
    """
    rng = np.random.default_rng() if rng is None else rng
    images = []
    for eye in (0, 1):
        img = background_dn + rng.normal(size=(height, width)) * noise_dn
        for lamp in lamps:
            margin = 6
            top = int(np.floor(lamp.v - 0.5 * lamp.height_px)) - margin
            n_rows = int(np.ceil(lamp.height_px)) + 2 * margin + 1
            levels = row_levels(lamp.signal, t0_s, n_rows, row_time_s, exposure_s,
                                first_row=top)
            u = lamp.u_left - eye * lamp.disparity_px
            n_cols = int(np.ceil(lamp.width_px)) + 2 * margin
            left_col = int(np.floor(u - 0.5 * (n_cols - 1)))
            du = u - (left_col + 0.5 * (n_cols - 1))
            dv = lamp.v - (top + 0.5 * (n_rows - 1))
            patch, _ = spot_patch(levels, lamp.width_px, lamp.height_px, gain_dn,
                                  psf_sigma_px, 0.0, 0.0, shot=True, rng=rng,
                                  margin_px=margin, centre_offset=(du, dv))
            paste(img, patch + background_dn, top, left_col)
        images.append(np.clip(np.rint(img), 0, 255).astype(np.uint8))
    return images[0], images[1]


def packet_period_s(chip_rate_hz=10_000.0):
    return PACKET_CHIPS / chip_rate_hz


@dataclass
class PassGeometry:
    """Pinhole view of wall lamps from a train passing at constant speed (paper set-up).

    The left camera sits ``lateral_m`` right of and ``height_m`` above the lamp line,
    its axis turned ``placement_deg`` from the wall normal toward the running direction
    (paper eq. 16) and tilted down by ``pitch_deg``; rectified stereo with ``baseline_m``.
    A lamp disc of ``diameter_m`` lies in the wall plane.
    """

    fx: float = 1040.0
    cx: float = 639.5
    cy: float = 359.5
    width: int = 1280
    height: int = 720
    baseline_m: float = 0.12
    lateral_m: float = 1.7
    height_m: float = 1.5
    placement_deg: float = 49.0
    pitch_deg: float = 26.0
    diameter_m: float = 0.2

    def _rotation(self):
        a, p = np.radians(self.placement_deg), np.radians(self.pitch_deg)
        # world: x along the track, y toward the wall, z up
        z0 = np.array([np.sin(a), np.cos(a), 0.0])
        x0 = np.array([np.cos(a), -np.sin(a), 0.0])
        y0 = np.array([0.0, 0.0, -1.0])
        z = np.cos(p) * z0 + np.sin(p) * y0
        y = np.cos(p) * y0 - np.sin(p) * z0
        return np.stack([x0, y, z])          # rows: camera axes in world

    def project(self, ahead_m, eye=0):
        """Pixel (u, v) and depth of a wall point ``ahead_m`` ahead (arrays)."""
        ahead_m = np.asarray(ahead_m, float)
        p = np.stack([ahead_m, np.full_like(ahead_m, self.lateral_m),
                      np.full_like(ahead_m, -self.height_m)], -1)
        rot = self._rotation()
        cam = p @ rot.T - np.array([eye * self.baseline_m, 0.0, 0.0])
        u = self.fx * cam[..., 0] / cam[..., 2] + self.cx
        v = self.fx * cam[..., 1] / cam[..., 2] + self.cy
        return u, v, cam[..., 2]

    def spot(self, ahead_m):
        """(u_left, v, disparity, width_px, height_px) of the lamp disc's image."""
        r = 0.5 * self.diameter_m
        u, v, _ = self.project(ahead_m)
        ur, _, _ = self.project(ahead_m, eye=1)
        rot = self._rotation()
        p = np.array([ahead_m, self.lateral_m, -self.height_m])
        extents = []
        for d in (np.array([r, 0, 0]), np.array([0, 0, r])):
            pts = [(p + s * d) @ rot.T for s in (-1, 1)]
            uv = [np.array([self.fx * q[0] / q[2], self.fx * q[1] / q[2]]) for q in pts]
            extents.append(np.abs(uv[1] - uv[0]))
        width = max(extents[0][0], extents[1][0])
        height = max(extents[0][1], extents[1][1])
        return float(u), float(v), float(u - ur), float(width), float(height)

    def visible(self, ahead_m):
        u, v, dis, w, h = self.spot(ahead_m)
        return (0 <= u - dis - 0.5 * w and u + 0.5 * w < self.width and
                0 <= v - 0.5 * h and v + 0.5 * h < self.height and ahead_m > 0)


def pass_frames(speed_kmh, lamp_uids, first_lamp_ahead_m=12.0, spacing_m=10.0,
                n_frames=None, frame_rate_hz=30.0, seed=0, clock_error=0.0,
                geometry=None, **render_kw):
    """Stereo frames of a train passing wall lamps at constant speed.

    Yields ``(stamp_ns, left, right, truth)`` with ``truth`` a list of dicts per lamp in
    view (uid, ahead_m, u, v, disparity). Lamp clocks get random phases and relative rate
    errors uniform in ±``clock_error``.
    """
    rng = np.random.default_rng(seed)
    geometry = PassGeometry() if geometry is None else geometry
    signals = [LampSignal(uid, chip_rate_hz=10_000.0 * (1 + rng.uniform(-1, 1) * clock_error),
                          phase_s=rng.uniform(0, 1)) for uid in lamp_uids]
    speed = speed_kmh / 3.6
    if n_frames is None:
        travel = first_lamp_ahead_m + spacing_m * (len(lamp_uids) - 1)
        n_frames = int(np.ceil(travel / max(speed, 1e-3) * frame_rate_hz)) + 1
    for k in range(n_frames):
        t = k / frame_rate_hz
        stamp_ns = int(round(t * 1e9))
        lamps, truth = [], []
        for i, signal in enumerate(signals):
            ahead = first_lamp_ahead_m + i * spacing_m - speed * t
            if ahead <= 0.05:
                continue
            u, v, disparity, width, height = geometry.spot(ahead)
            if u - disparity - width > geometry.width or u + width < 0 or \
                    v - height > geometry.height or v + height < 0:
                continue
            lamps.append(SyntheticLamp(signal, u, v, disparity, width, height))
            truth.append({'uid': signal.uid, 'ahead_m': ahead, 'u': u, 'v': v,
                          'disparity': disparity, 'width': width, 'height': height})
        left, right = render_stereo(lamps, t, rng=rng, **render_kw)
        yield stamp_ns, left, right, truth


# ---------------------------------------------------------------------- fuzz profiles
FUZZ_ROWS = 200       # 6 ms of rows: one packet (5.4 ms) plus a margin
FUZZ_KINDS = ('random_noise', 'random_chips', 'chip_flips', 'pair_flips', 'wrong_rate',
              'truncated', 'noise')


def _crc8_table_text():
    """CRC-8/SMBUS table, bit by bit from the protocol text (poly 0x07, MSB first)."""
    table = []
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = ((crc << 1) ^ 0x07) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
        table.append(crc)
    return np.array(table)


_TEXT_CRC8 = _crc8_table_text()


def text_packets(uids):
    """(N, 54) chips of the packets of ``uids``, vectorised from the protocol text:
    header 111000, then line_id‖lamp_id‖CRC-8 MSB first, bit 1 → 10, bit 0 → 01.
    """
    uids = np.asarray(uids, dtype=np.int64)
    crc = _TEXT_CRC8[_TEXT_CRC8[uids >> 8] ^ (uids & 0xFF)]
    word = (uids << 8) | crc
    bits = (word[:, None] >> np.arange(23, -1, -1)[None, :]) & 1
    data = np.stack([bits, 1 - bits], axis=2).reshape(len(uids), 48)
    header = np.broadcast_to([1, 1, 1, 0, 0, 0], (len(uids), 6))
    return np.concatenate([header, data], axis=1)


def text_packet_uids(packet):
    """UID a (possibly corrupted) (N, 54) packet carries if it is a valid one, else −1."""
    bits = packet[:, 6::2].astype(np.int64)
    word = (bits * (1 << np.arange(23, -1, -1))).sum(axis=1)
    uid, crc = word >> 8, word & 0xFF
    valid = _TEXT_CRC8[_TEXT_CRC8[uid >> 8] ^ (uid & 0xFF)] == crc
    return np.where(valid, uid, -1)


def render_streams(stream, phase_chips, rate_scale, row_time_s=30e-6, exposure_s=50e-6,
                   chip_rate_hz=10_000.0, off_level=0.05, n_rows=FUZZ_ROWS):
    """Normalised row levels (N, n_rows) of chip streams (N, S), exactly integrated.

    Row 0's exposure starts ``phase_chips`` (N,) chips into each stream; each stream's
    rate is ``chip_rate_hz·rate_scale`` (N,).
    """
    n, s = stream.shape
    levels = off_level + (1 - off_level) * stream
    cum = np.concatenate([np.zeros((n, 1)), np.cumsum(levels, axis=1)], axis=1)
    start = np.arange(n_rows) * row_time_s
    rate = chip_rate_hz * np.asarray(rate_scale, float)[:, None]

    def integral(t):
        x = np.clip(t[None, :] * rate + np.asarray(phase_chips, float)[:, None], 0, s - 1e-9)
        k = np.floor(x).astype(np.int64)
        return (np.take_along_axis(cum, k, axis=1)
                + (x - k) * np.take_along_axis(levels, k, axis=1))

    mean = (integral(start + exposure_s) - integral(start)) / (exposure_s * rate)
    return (mean - off_level) / (1 - off_level)


def fuzz_profiles(rng, kind, n, cfg=None):
    """A batch of random or corrupted stripe profiles and the UID each truly carries.

    Kinds: ``random_noise`` (uniform levels), ``random_chips`` (i.i.d. chips),
    ``chip_flips`` (1–8 chips of the stream inverted), ``pair_flips`` (1–6 data bits
    inverted in every packet: still Manchester; with four or more the packet may be
    another valid codeword — CRC-8/0x07 has Hamming distance 4 at 24 bits — and that UID
    is then what was sent), ``wrong_rate`` (chip rate off by 2.5–20 %), ``truncated``
    (10–185 rows kept), ``noise`` (level gain/offset errors and noise σ 0.05–0.6).

    ``cfg`` (a DecoderConfig; default the protocol's 10 kchip/s, 30 µs rows, 50 µs
    exposure) sets the row timing, chip rate and off level the profiles are rendered with.

    Returns
    -------
    truth : (N,) the UID each profile carries, −1 where it carries none
    y : (N, FUZZ_ROWS) normalised levels; w : (N, FUZZ_ROWS) row weights
    """
    timing = {} if cfg is None else {
        'row_time_s': cfg.row_time_s, 'exposure_s': cfg.exposure_s,
        'chip_rate_hz': cfg.chip_rate_hz, 'off_level': cfg.off_level}
    row_time = timing.get('row_time_s', 30e-6)
    chip_rate = timing.get('chip_rate_hz', 10_000.0)
    # the stream covers every row at the fastest corrupted rate, after the start phase
    length = int(np.ceil((FUZZ_ROWS * row_time + 1e-4) * chip_rate * 1.25)) + PACKET_CHIPS
    uids = rng.integers(0, 1 << 16, n)
    packet = text_packets(uids).astype(float)
    stream = np.tile(packet, length // 54 + 2)[:, :length]
    phase = rng.uniform(0, 54, n)
    rate = np.ones(n)
    w = np.ones((n, FUZZ_ROWS))
    truth = uids.copy()
    if kind == 'random_noise':
        return np.full(n, -1), rng.uniform(-0.3, 1.3, (n, FUZZ_ROWS)), w
    if kind == 'random_chips':
        stream = rng.integers(0, 2, (n, length)).astype(float)
        truth[:] = -1
    elif kind == 'chip_flips':
        for i in range(n):
            idx = rng.choice(length, rng.integers(1, 9), replace=False)
            stream[i, idx] = 1 - stream[i, idx]
    elif kind == 'pair_flips':
        for i in range(n):
            bits = rng.choice(24, rng.integers(1, 7), replace=False)
            packet[i, 6 + 2 * bits] = 1 - packet[i, 6 + 2 * bits]
            packet[i, 7 + 2 * bits] = 1 - packet[i, 7 + 2 * bits]
        stream = np.tile(packet, length // 54 + 2)[:, :length]
        truth = text_packet_uids(packet)
    elif kind == 'wrong_rate':
        rate = 1 + rng.choice([-1, 1], n) * rng.uniform(0.025, 0.2, n)
    elif kind == 'truncated':
        keep = rng.integers(10, 185, n)
        first = rng.integers(0, FUZZ_ROWS - keep)
        rows = np.arange(FUZZ_ROWS)[None, :]
        w = ((rows >= first[:, None]) & (rows < (first + keep)[:, None])).astype(float)
    elif kind not in FUZZ_KINDS:
        raise ValueError(f'unknown fuzz kind {kind!r}')
    y = render_streams(stream, phase, rate, **timing)
    if kind == 'noise':
        y = y * rng.uniform(0.6, 1.4, (n, 1)) + rng.uniform(-0.3, 0.3, (n, 1))
        y = y + rng.normal(size=y.shape) * rng.uniform(0.05, 0.6, (n, 1))
    else:
        y = y + rng.normal(size=y.shape) * 0.03
    return truth, y, w


def fuzz_run(decode, count_per_kind, seed=20240101, chunk=10_000, cfg=None):
    """Run ``decode(y, w) -> uid`` over fuzz profiles of every kind (rendered with the
    timing of ``cfg``, see :func:`fuzz_profiles`).

    Returns a dict per kind: profiles, accepted, correct, wrong (accepted with a UID the
    profile does not carry).
    """
    rng = np.random.default_rng(seed)
    out = {}
    for kind in FUZZ_KINDS:
        stats = {'profiles': 0, 'accepted': 0, 'correct': 0, 'wrong': 0}
        left = count_per_kind
        while left > 0:
            n = min(chunk, left)
            left -= n
            truth, y, w = fuzz_profiles(rng, kind, n, cfg)
            uid = decode(y, w)
            got = uid >= 0
            right = got & (uid == truth)
            stats['profiles'] += n
            stats['accepted'] += int(got.sum())
            stats['correct'] += int(right.sum())
            stats['wrong'] += int((got & ~right).sum())
        out[kind] = stats
    return out
