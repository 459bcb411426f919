"""The camera of one photo: scaled orthographic projection (weak perspective).

A face photographed from a normal distance is close to an orthographic view scaled by the
distance: Lee et al. (1999) take their front and side photos as exactly orthogonal views; we
solve each view's own rotation instead (views that are not exactly front and side), and keep
the projection orthographic, which is what makes triangulation from two views linear.

    pixel (x right, y down) = scale * [1, -1] * (R @ X)[:2] + offset
    depth = (R @ X)[2]            (larger is nearer the camera: the camera looks along -z)

``R`` turns head coordinates (x the subject's left, y up, z forward out of the face) into
camera coordinates (x right in the image, y up, z towards the camera).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class ViewCamera:
    """Scaled orthographic camera of one photo (see the module docstring)."""

    rotation: np.ndarray  # (3, 3)
    scale: float  # pixels per head unit
    offset: np.ndarray  # (2,) pixels
    size: tuple[int, int]  # (width, height) of the photo in pixels

    def project(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) head points -> (N, 2) pixels (x right, y down)."""
        p = np.asarray(points, dtype=np.float64) @ self.rotation.T
        return self.scale * p[:, :2] * np.array([1.0, -1.0]) + self.offset

    def depth(self, points: np.ndarray) -> np.ndarray:
        """(N,) distance towards the camera (larger is nearer)."""
        return np.asarray(points, dtype=np.float64) @ self.rotation[2]

    @property
    def direction(self) -> np.ndarray:
        """(3,) unit vector from the head towards the camera, in head coordinates."""
        return self.rotation[2].copy()

    @property
    def matrix(self) -> np.ndarray:
        """(2, 3) linear part of :meth:`project`."""
        return self.scale * self.rotation[:2] * np.array([[1.0], [-1.0]])

    @property
    def yaw_degrees(self) -> float:
        """How far the head is turned from this camera about the vertical axis: positive when the
        subject's left (+x) faces the camera, i.e. the nose points to the image's left."""
        d = self.direction
        return float(np.degrees(np.arctan2(d[0], d[2])))
