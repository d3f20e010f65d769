"""The downward camera's lens: pinhole + OpenCV radial-tangential distortion, and its rectified
(undistorted) pinhole image, L(32) and L(34).

The camera publishes distorted images (or distorted keypoint pixels); perception works in the
rectified image: the same size, focal length `rectified_scale` x f, centred, no distortion. There the
projection is L(32) and its Jacobian L(34) with D = I (the distortion is removed before measuring).
The calibration travels with every frame as a plain dict (`Lens.calibration()`), as a calibrated
real camera's would.
"""
import dataclasses as dc

import cv2
import numpy as np

_UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-10)


@dc.dataclass(frozen=True)
class Lens:
    """K (3x3, distorted image), distortion (k1, k2, p1, p2, k3), size, rectified K, X_BC (4x4)."""
    K: np.ndarray
    distortion: np.ndarray
    width: int
    height: int
    K_rectified: np.ndarray
    X_BC: np.ndarray

    @staticmethod
    def from_calibration(calibration: dict) -> "Lens":
        return Lens(np.asarray(calibration["K"], float),
                    np.asarray(calibration["distortion"], float), int(calibration["width"]),
                    int(calibration["height"]), np.asarray(calibration["K_rectified"], float),
                    np.asarray(calibration["X_BC"], float))

    @staticmethod
    def make(width: int, height: int, focal_length: float, distortion, rectified_scale: float,
             X_BC: np.ndarray) -> "Lens":
        K = np.array([[focal_length, 0, (width - 1) / 2], [0, focal_length, (height - 1) / 2],
                      [0, 0, 1.0]])
        K_rectified = K.copy()
        K_rectified[0, 0] = K_rectified[1, 1] = focal_length * rectified_scale
        return Lens(K, np.asarray(distortion, float), width, height, K_rectified,
                    np.asarray(X_BC, float))

    def calibration(self) -> dict:
        return {"K": self.K.copy(), "distortion": self.distortion.copy(), "width": self.width,
                "height": self.height, "K_rectified": self.K_rectified.copy(),
                "X_BC": self.X_BC.copy(), "model": "opencv_radtan"}

    # --- distorted image --------------------------------------------------------------------
    def project(self, p_C: np.ndarray) -> np.ndarray:
        """Distorted pixels (N, 2) of points (N, 3) in the camera frame (z > 0 required)."""
        p_C = np.asarray(p_C, float).reshape(-1, 3)
        uv, _ = cv2.projectPoints(p_C, np.zeros(3), np.zeros(3), self.K, self.distortion)
        return uv.reshape(-1, 2)

    def normalized(self, uv: np.ndarray) -> np.ndarray:
        """Undistorted normalized coordinates (x/z, y/z) (N, 2) of distorted pixels (N, 2)."""
        uv = np.asarray(uv, np.float64).reshape(-1, 1, 2)
        if uv.shape[0] == 0:
            return np.zeros((0, 2))
        xy = cv2.undistortPointsIter(uv, self.K, self.distortion, None, None, _UNDISTORT_CRITERIA)
        return xy.reshape(-1, 2)

    def in_image(self, uv: np.ndarray, margin: float = 0.0) -> np.ndarray:
        uv = np.asarray(uv).reshape(-1, 2)
        return (uv[:, 0] >= margin) & (uv[:, 0] <= self.width - 1 - margin) & \
            (uv[:, 1] >= margin) & (uv[:, 1] <= self.height - 1 - margin)

    # --- rectified image ----------------------------------------------------------------------
    def rectify_points(self, uv: np.ndarray) -> np.ndarray:
        """Rectified pixels of distorted pixels."""
        xy = self.normalized(uv)
        return xy @ self.K_rectified[:2, :2].T + self.K_rectified[:2, 2]

    def rectified_project(self, p_C: np.ndarray) -> np.ndarray:
        """L(32): rectified pixels (N, 2) of points (N, 3) in the camera frame."""
        p_C = np.asarray(p_C, float).reshape(-1, 3)
        return p_C[:, :2] / p_C[:, 2:3] @ self.K_rectified[:2, :2].T + self.K_rectified[:2, 2]

    def rectified_jacobian(self, p_C: np.ndarray) -> np.ndarray:
        """L(34) with D = I: d u / d p_C (2x3) at one point."""
        x, y, z = p_C
        f = self.K_rectified
        return np.array([[f[0, 0] / z, 0.0, -f[0, 0] * x / z ** 2],
                         [0.0, f[1, 1] / z, -f[1, 1] * y / z ** 2]])

    def rectify_maps(self) -> tuple[np.ndarray, np.ndarray]:
        """cv2.remap maps from the distorted image to the rectified image."""
        return cv2.initUndistortRectifyMap(self.K, self.distortion, None, self.K_rectified,
                                           (self.width, self.height), cv2.CV_16SC2)

    def field_of_view(self) -> tuple[float, float]:
        """Horizontal and vertical field of view [deg] of the distorted image."""
        w, h = self.width - 1, self.height - 1
        xy = self.normalized(np.array([[0, h / 2], [w, h / 2], [w / 2, 0], [w / 2, h]]))
        return (float(np.degrees(np.arctan(-xy[0, 0]) + np.arctan(xy[1, 0]))),
                float(np.degrees(np.arctan(-xy[2, 1]) + np.arctan(xy[3, 1]))))
