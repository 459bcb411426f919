"""Camera framing and the OpenGL matrices (pure numpy, no GL)."""

from __future__ import annotations

import numpy as np

from faceanim.errors import FaceAnimError

# the perspective camera looks from this far: the framed half-height subtends ~15 degrees x 1/4
LOOK_FROM_DEGREES = 15.0


def view_rotation(forward: str = "+z", up: str = "+y") -> np.ndarray:
    """Rotation taking mesh coordinates to view coordinates (face looks along +z, y up)."""
    axes = {"x": 0, "y": 1, "z": 2}

    def vec(s: str) -> np.ndarray:
        s = s.strip().lower()
        if len(s) == 1:
            s = "+" + s
        if len(s) != 2 or s[0] not in "+-" or s[1] not in axes:
            raise FaceAnimError(f"axis '{s}' not understood; use one of +x, -x, +y, -y, +z, -z")
        v = np.zeros(3)
        v[axes[s[1]]] = 1.0 if s[0] == "+" else -1.0
        return v

    f, u = vec(forward), vec(up)
    if abs(f @ u) > 0.5:
        raise FaceAnimError(f"forward '{forward}' and up '{up}' must be different axes")
    x = np.cross(u, f)
    return np.vstack([x, u, f])


class Camera:
    """Where the camera is and what it sees, in view coordinates (the mesh after ``rotation``).

    The box of ``frame_vertices`` (view coordinates) times ``margin`` fills the image; the camera
    turns ``yaw`` degrees around the vertical axis through the box centre (positive: from the
    subject's left, +x) and ``pitch`` degrees up, looking at the centre from
    ``4 * parallel_scale / tan(15 deg)`` away, with a perspective or a parallel projection.
    """

    def __init__(self, frame_vertices: np.ndarray, size: tuple[int, int], yaw: float = 0.0,
                 pitch: float = 0.0, parallel: bool = False, margin: float = 1.08):
        fv = np.asarray(frame_vertices, dtype=np.float64).reshape(-1, 3)
        if not len(fv) or not np.all(np.isfinite(fv)):
            raise FaceAnimError("the camera needs finite vertices to frame")
        self.size = (int(size[0]), int(size[1]))
        lo, hi = fv.min(0), fv.max(0)
        self.centre = (lo + hi) / 2
        self.half = (hi - lo) / 2 * margin
        self.aspect = self.size[0] / self.size[1]
        self.parallel_scale = float(max(self.half[1], self.half[0] / self.aspect))
        self.parallel = bool(parallel)
        self.distance = 4.0 * max(self.parallel_scale, 1e-9) / np.tan(np.radians(LOOK_FROM_DEGREES))
        yaw_r, pitch_r = np.radians(yaw), np.radians(pitch)
        self.direction = np.array([np.sin(yaw_r) * np.cos(pitch_r), np.sin(pitch_r),
                                   np.cos(yaw_r) * np.cos(pitch_r)])  # from the centre to the eye
        self.eye = self.centre + self.distance * self.direction
        reach = 4 * float(np.linalg.norm(self.half)) + 1e-6
        self.near = self.distance - reach
        if not parallel:
            self.near = max(self.near, 1e-3 * self.distance)
        self.far = self.distance + reach

    def view_matrix(self) -> np.ndarray:
        """4x4 world (view coordinates) -> eye coordinates, y up, looking down -z."""
        f = -self.direction
        up = np.array([0.0, 1.0, 0.0])
        if np.linalg.norm(np.cross(f, up)) < 1e-6:  # looking straight up or down
            up = np.array([0.0, 0.0, -1.0 if f[1] < 0 else 1.0])
        r = np.cross(f, up)
        r /= np.linalg.norm(r)
        u = np.cross(r, f)
        m = np.eye(4)
        m[0, :3], m[1, :3], m[2, :3] = r, u, -f
        m[:3, 3] = -m[:3, :3] @ self.eye
        return m

    def projection_matrix(self) -> np.ndarray:
        """4x4 eye -> clip coordinates (OpenGL conventions, depth -1..1)."""
        n, f, s = self.near, self.far, max(self.parallel_scale, 1e-12)
        p = np.zeros((4, 4))
        if self.parallel:
            p[0, 0], p[1, 1] = 1.0 / (s * self.aspect), 1.0 / s
            p[2, 2], p[2, 3], p[3, 3] = -2.0 / (f - n), -(f + n) / (f - n), 1.0
        else:
            cot = self.distance / s  # half-height s at the centre's distance
            p[0, 0], p[1, 1] = cot / self.aspect, cot
            p[2, 2], p[2, 3], p[3, 2] = (f + n) / (n - f), 2 * f * n / (n - f), -1.0
        return p
