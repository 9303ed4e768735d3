"""Pinhole stereo camera model of the rig: intrinsics, mounting, projection.

Frames: ``base_link`` (x forward, y left, z up) and the optical frames (z forward,
x right, y down). The left camera's optical centre is at ``mount_xyz_m`` in
``base_link``; the right camera sits ``baseline_m`` further along the left optical x
axis with the same orientation (rectified stereo, parallel axes).

Mounting: the optical axis is turned from the left-wall normal (+y of ``base_link``)
toward the running direction (+x) by the placement angle (paper eq. 16, 49°) and tilted
down by ``pitch_deg``.
"""
from dataclasses import dataclass

import numpy as np


@dataclass
class CameraIntrinsics:
    """Paper camera: f = 3.9 mm, 3.75 µm pixels → 1040 px; 1280×720; no distortion."""

    width: int = 1280
    height: int = 720
    fx: float = 1040.0
    fy: float = 1040.0
    cx: float = 639.5
    cy: float = 359.5

    def __post_init__(self):
        if self.width <= 0 or self.height <= 0 or self.fx <= 0 or self.fy <= 0:
            raise ValueError('camera width, height, fx and fy must be positive')

    @property
    def K(self):
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def fov_deg(self):
        """(horizontal, vertical) full field of view in degrees."""
        return (np.degrees(2 * np.arctan(self.width / (2 * self.fx))),
                np.degrees(2 * np.arctan(self.height / (2 * self.fy))))


def mount_rotation(placement_angle_deg, pitch_deg):
    """R_base_cam (3, 3): columns are the optical x, y, z axes expressed in base_link."""
    a, p = np.radians(placement_angle_deg), np.radians(pitch_deg)
    z0 = np.array([np.sin(a), np.cos(a), 0.0])    # toward the wall, turned forward
    x0 = np.array([np.cos(a), -np.sin(a), 0.0])   # image right
    y0 = np.array([0.0, 0.0, -1.0])               # image down
    z = np.cos(p) * z0 + np.sin(p) * y0           # tilted down by the pitch
    y = np.cos(p) * y0 - np.sin(p) * z0
    return np.column_stack([x0, y, z])


@dataclass
class StereoRig:
    """Rectified stereo pair rigidly mounted on ``base_link``."""

    intrinsics: CameraIntrinsics = None
    baseline_m: float = 0.12
    mount_xyz_m: tuple = (0.0, 0.8, 2.9)
    placement_angle_deg: float = 49.0
    pitch_deg: float = 27.0

    def __post_init__(self):
        if self.intrinsics is None:
            self.intrinsics = CameraIntrinsics()
        if not self.baseline_m > 0.0:
            raise ValueError('baseline_m must be > 0')
        self.R_base_cam = mount_rotation(self.placement_angle_deg, self.pitch_deg)
        left = np.asarray(self.mount_xyz_m, dtype=float)
        self.t_base_cams = np.stack([left, left + self.baseline_m * self.R_base_cam[:, 0]])

    def cam_positions_base(self):
        """(2, 3) optical centres of the left and right cameras in ``base_link`` (m)."""
        return self.t_base_cams.copy()

    def to_camera(self, points_map, base_pos_map, R_map_base, camera=0):
        """Points in ``map`` (N, 3) → camera ``camera`` (0 left, 1 right) optical frame.

        ``base_pos_map`` (3,) or (N, 3) and ``R_map_base`` (3, 3) or (N, 3, 3) may be
        given per point (rolling shutter: each point seen at its own instant).
        """
        p = np.asarray(points_map, dtype=float).reshape(-1, 3)
        base = np.broadcast_to(np.asarray(base_pos_map, dtype=float), p.shape)
        R = np.broadcast_to(np.asarray(R_map_base, dtype=float), (p.shape[0], 3, 3))
        p_base = np.einsum('nji,nj->ni', R, p - base)          # R^T (p - base)
        return (p_base - self.t_base_cams[camera]) @ self.R_base_cam

    def project_camera(self, p_cam):
        """Optical-frame points (N, 3) → pixel (N, 2) (u right, v down) and depth (N,)."""
        k = self.intrinsics
        z = p_cam[:, 2]
        with np.errstate(divide='ignore', invalid='ignore'):
            uv = np.stack([k.fx * p_cam[:, 0] / z + k.cx, k.fy * p_cam[:, 1] / z + k.cy], 1)
        return uv, z

    def project(self, points_map, base_pos_map, R_map_base):
        """Project map points into both cameras.

        Returns ``uv_left`` (N, 2), ``uv_right`` (N, 2) in pixels and ``depth_left`` (N,)
        in metres (the optical z of the left camera; equal for both in rectified stereo).
        """
        uv_l, z_l = self.project_camera(self.to_camera(points_map, base_pos_map, R_map_base, 0))
        uv_r, _ = self.project_camera(self.to_camera(points_map, base_pos_map, R_map_base, 1))
        return uv_l, uv_r, z_l

    def camera_info_dicts(self):
        """CameraInfo contents (K, R, P, D, size) for the left and right cameras.

        Rectified pair: R = I, right ``P[0,3] = −fx·baseline`` (image_geometry layout).
        """
        k = self.intrinsics
        infos = []
        for cam in (0, 1):
            P = np.zeros((3, 4))
            P[:, :3] = k.K
            P[0, 3] = -k.fx * self.baseline_m * cam
            infos.append({'width': k.width, 'height': k.height, 'K': k.K, 'D': np.zeros(5),
                          'R': np.eye(3), 'P': P, 'distortion_model': 'plumb_bob'})
        return infos
