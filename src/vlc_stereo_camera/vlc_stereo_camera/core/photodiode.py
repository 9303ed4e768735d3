"""Photodiode on the train head: each lamp's received optical power (VLC + RSSI), drawn
through the optical channel of :mod:`vlc_common.core.optical_channel` along the rig's
trajectory, with each lamp's true power and the sample noise.
"""
from dataclasses import dataclass
import math

import numpy as np

from vlc_common.core.optical_channel import (
    channel_gain,
    noise_variance_a2,
    photodiode_pose,
)

#: Seed-sequence tag of the photodiode's random streams (independent of the camera's
#: and the IMU's streams drawn from the same scenario seed).
SEED_TAG = 0x9D0D
#: Lamps farther along the track than this are not evaluated, m. Only a pick of
#: candidates: even a 89° field of view sees the lamp line (2.3 m away) out to 130 m,
#: where H(0) is 1e-6 of the nearest lamp's; the default 80° ends at 13 m.
CANDIDATE_REACH_M = 60.0


@dataclass
class PhotodiodeSample:
    """Per-lamp power estimates of one sample window.

    Attributes
    ----------
    t_s : float
        Window mid-time, s since the simulation epoch (the sample's stamp).
    uid : ndarray (K,) uint32
        Lamps received with SNR ≥ ``min_snr_db``.
    power_w : ndarray (K,)
        Estimated received "on" power of each lamp, W (window mean + noise).
    power_sigma_w : ndarray (K,)
        1σ of the noise of each estimate, W.
    snr_db : ndarray (K,)
        10·log10((R·P)² / σ²) of each estimate, dB.
    true_power_w : ndarray (K,)
        Noise-free window-mean power (tests and diagnostics only), W.
    """

    t_s: float
    uid: np.ndarray
    power_w: np.ndarray
    power_sigma_w: np.ndarray
    snr_db: np.ndarray
    true_power_w: np.ndarray


class Photodiode:
    """The train-head PD riding a :class:`~.trajectory.Trajectory` past a lamp map.

    Parameters
    ----------
    config : PhotodiodeConfig
    lamp_map : vlc_common.core.lamp_map.LampMap
    trajectory : vlc_stereo_camera.core.trajectory.Trajectory
    seed : int
        Scenario seed; per-lamp power factors and per-sample noise are drawn from
        ``SeedSequence([seed, SEED_TAG, …])`` keyed by UID and sample index, so a sample
        is the same whatever was computed before it.
    subsamples : int
        Instants averaged over a window (the channel changes within 20 ms at speed).
    """

    def __init__(self, config, lamp_map, trajectory, seed=0, subsamples=5):
        if subsamples < 1:
            raise ValueError('subsamples must be >= 1')
        self.config = config
        self.lamp_map = lamp_map
        self.trajectory = trajectory
        self.seed = int(seed)
        self.subsamples = int(subsamples)
        self._factor = {}

    def power_factor(self, uid):
        """1 + ε: the lamp's actual optical power over the nominal (seeded per UID)."""
        uid = int(uid)
        if uid not in self._factor:
            rng = np.random.default_rng([self.seed, SEED_TAG, 1, uid])
            self._factor[uid] = max(0.0, 1.0 + self.config.lamp_power_sigma_rel
                                    * float(rng.standard_normal()))
        return self._factor[uid]

    def true_powers(self, t_mid_s, window_s):
        """Noise-free window-mean received "on" power of the candidate lamps.

        Returns (lamps (list of Lamp), power_w (L,)).
        """
        cfg = self.config
        k = np.arange(self.subsamples)
        t = t_mid_s + ((k + 0.5) / self.subsamples - 0.5) * window_s
        truth = self.trajectory.sample(t)
        pos, normal = photodiode_pose(truth.position_m, truth.R_map_base, cfg)
        lamps = self.lamp_map.near(float(pos[:, 0].mean()), CANDIDATE_REACH_M, CANDIDATE_REACH_M)
        if not lamps:
            return [], np.zeros(0)
        lamp_pos = np.array([lamp.position_m for lamp in lamps])
        lamp_n = np.array([lamp.normal for lamp in lamps])
        gain, _, _, _ = channel_gain(pos, normal, lamp_pos, lamp_n, cfg)
        factors = np.array([self.power_factor(lamp.uid) for lamp in lamps])
        return lamps, cfg.lamp_optical_power_w * factors * gain.mean(axis=0)

    def sample(self, index, rate_hz):
        """Sample ``index``: the window of length 1/rate centred on t = index/rate.

        Returns
        -------
        PhotodiodeSample
        """
        cfg = self.config
        window = 1.0 / rate_hz
        t_mid = index / rate_hz
        lamps, power = self.true_powers(t_mid, window)
        keep = power > 0.0
        lamps = [lamp for lamp, k in zip(lamps, keep) if k]
        power = power[keep]
        sigma_a = math.sqrt(float(noise_variance_a2(power.sum(), cfg)))
        sigma_w = np.full(power.shape, sigma_a / cfg.responsivity_a_per_w)
        rng = np.random.default_rng([self.seed, SEED_TAG, 2, int(index)])
        measured = power + sigma_w * rng.standard_normal(power.shape)
        with np.errstate(divide='ignore'):
            snr_db = 20.0 * np.log10(np.abs(measured) / sigma_w)
        ok = snr_db >= cfg.min_snr_db
        uid = np.array([lamp.uid for lamp in lamps], dtype=np.uint32)
        return PhotodiodeSample(t_s=t_mid, uid=uid[ok], power_w=measured[ok],
                                power_sigma_w=sigma_w[ok], snr_db=snr_db[ok],
                                true_power_w=power[ok])
