"""Rectification of the split images with the stereo calibration (optional in the node).

The receivers read only P from camera_info and take the images for a rectified pair
(docs/arch/calibration.md, "What is not wired yet"). A real lens is not: with
``rectify`` on, each half is remapped through its camera's K, D, R, P (the maps of
``cv2.initUndistortRectifyMap``, as ``image_proc`` does) and described by the camera_info
of an ideal rectified camera (K = P[:, :3], D = 0, R = I, P unchanged).
"""
import cv2
import numpy as np


class Rectifier:
    """Remaps one camera's raw images to its rectified image.

    Parameters
    ----------
    camera : vlc_common.core.camera.CameraModel
        The camera (K, D, R, P, size).
    """

    def __init__(self, camera):
        self.size = (int(camera.width), int(camera.height))
        self.identity = (not np.any(camera.D) and np.allclose(camera.R, np.eye(3))
                         and np.allclose(camera.P[:, :3], camera.K))
        self._maps = None
        if not self.identity:
            self._maps = cv2.initUndistortRectifyMap(
                np.asarray(camera.K, float), np.asarray(camera.D, float),
                np.asarray(camera.R, float), np.asarray(camera.P[:, :3], float),
                self.size, cv2.CV_16SC2)

    def __call__(self, image):
        """(H, W) raw image → (H, W) rectified image (bilinear; the input itself when the
        camera is already rectified: D = 0, R = I, P = [K | t]).
        """
        if self._maps is None:
            return image
        return cv2.remap(image, self._maps[0], self._maps[1], cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_CONSTANT, borderValue=0)


def rectified_camera_info(info):
    """The camera_info dict of a rectified image: K = P[:, :3], D = 0, R = I, P kept."""
    P = np.asarray(info['P'], float).reshape(3, 4)
    return dict(info, K=P[:, :3].copy(), D=np.zeros(5), R=np.eye(3), P=P.copy(),
                distortion_model='plumb_bob')
