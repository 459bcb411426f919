"""The Face: a mesh plus its 478 landmarks, with the derived geometry every method needs cached.

Every command starts from a Face (``Face.load``) and every rig is built on one: the face frame
(nose-tip origin, eye and mouth scales), the skin shell, the sides of the mouth and eye slits,
the visible face and the region an expression may move, and the MPEG-4 feature points with their
FAPU are computed once, on first use, and kept with the face.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from faceanim.deform.rbf import landmark_tps
from faceanim.errors import LandmarkError
from faceanim.face.landmarks import BASIC22, Landmarks
from faceanim.face.mesh import Mesh

# how a face is shown in PNGs and MP4s: the face oval plus 30%, seen from 10 degrees to its left and
# 3 degrees above
VIEW_MARGIN, VIEW_YAW, VIEW_PITCH = 1.3, 10.0, 3.0
# the face oval with this margin frames a whole head (the neck cut off)
HEAD_MARGIN = 1.9


def landmarks_478(mesh: Mesh, landmarks: Landmarks) -> np.ndarray:
    """All 478 MediaPipe landmark positions on ``mesh``.

    Taken directly when ``landmarks`` has them; from the basic 22 by a landmark thin-plate
    spline from faceanim's default face (thesis 5.6.1) and snapping onto ``mesh`` otherwise.
    """
    where = {int(i): k for k, i in enumerate(landmarks.indices)}
    if all(i in where for i in range(478)):
        return landmarks.positions[[where[i] for i in range(478)]]
    need = [i for _, i in BASIC22]
    missing = [n for n, i in BASIC22 if i not in where]
    if missing:
        raise LandmarkError(
            f"action units need the 478 MediaPipe landmarks or the basic 22; missing: {', '.join(missing[:6])}"
            + (" ..." if len(missing) > 6 else "") + " (run `faceanim landmarks` on the mesh)")
    from faceanim.face.default import default_landmarks

    ref = default_landmarks().positions
    tps = landmark_tps(ref[need], landmarks.positions[[where[i] for i in need]], "basic 22 landmarks")
    moved = tps(ref)
    pos, _, _ = mesh.closest_points(moved)
    return pos


def check_face_size(mesh: Mesh) -> None:
    """Refuse a face mesh too large to rig in a few GB (:data:`~faceanim.limits.MAX_FACE_VERTICES`)."""
    from faceanim.errors import MeshError
    from faceanim.limits import MAX_FACE_VERTICES

    if mesh.n_vertices > MAX_FACE_VERTICES:
        raise MeshError(f"face mesh '{mesh.name}' has {mesh.n_vertices:,} vertices; faces of up to "
                        f"{MAX_FACE_VERTICES:,} are rigged (about 10 kB of memory per vertex): decimate it "
                        "(e.g. Blender's Decimate modifier) and try again")


@dataclass(eq=False)
class Face:
    """A mesh and its 478 MediaPipe landmark positions (``landmarks`` (478, 3), on the surface).

    Build one with :meth:`load` (a mesh file, its landmarks from a file or detected) or
    :meth:`default` (the embedded default face, a whole head whose landmarks are attached to its
    triangles: nothing is detected).
    """

    mesh: Mesh
    landmarks: np.ndarray

    def __post_init__(self):
        check_face_size(self.mesh)
        lm = np.asarray(self.landmarks, dtype=np.float64)
        if lm.shape != (478, 3) or not np.all(np.isfinite(lm)):
            raise LandmarkError(f"a face needs the 478 MediaPipe landmark positions, got shape {lm.shape}")
        self.landmarks = lm

    # ------------------------------------------------------------------ building
    @classmethod
    def default(cls) -> Face:
        """The embedded default face (a textured full head) with its embedded landmarks."""
        from faceanim.face.default import default_face, default_landmarks

        mesh = default_face()
        return cls(mesh, default_landmarks(mesh).positions)

    @classmethod
    def load(cls, path=None, landmarks=None, forward: str = "+z", up: str = "+y") -> Face:
        """A face from a mesh file (``None`` or ``"default"``: the embedded default face) and its
        landmarks: from a JSON file (the 478 points or the basic 22, snapped onto the mesh) or,
        without one, read off the topology of a head made from the generic head (``faceanim
        photo``, the default face: its landmarks sit on known triangles), or else detected by
        rendering the mesh and running MediaPipe."""
        from faceanim.face.landmarks import Landmarks, detect_landmarks
        from faceanim.io.meshio import load_mesh

        if path in (None, "default") and landmarks is None:
            return cls.default()
        if path in (None, "default"):
            from faceanim.face.default import default_face

            mesh = default_face()
        else:
            mesh = load_mesh(path)
        check_face_size(mesh)  # before anything is rendered or bound
        if landmarks is not None:
            lms = Landmarks.load(landmarks).attached_to(mesh)
        else:
            from faceanim.face.generic_head import generic_head

            known = generic_head().landmarks_on(mesh)
            if known is not None:
                return cls(mesh, known)
            lms = detect_landmarks(mesh, forward=forward, up=up)
        from faceanim.face.registration import check_face

        face = cls(mesh, landmarks_478(mesh, lms))
        check_face(face)  # landmarks that fit no head (a sphere's, a torus's) are not a face's
        return face

    # ------------------------------------------------------------------ derived geometry
    @property
    def name(self) -> str:
        return self.mesh.name

    @cached_property
    def frame(self):
        """The face's own frame (:class:`~faceanim.face.frame.FaceFrame`)."""
        from faceanim.face.frame import face_frame

        return face_frame(self.landmarks)

    @cached_property
    def skin(self) -> np.ndarray:
        """(V,) bool: the skin shell (no eyeballs, teeth or tongue shells)."""
        from faceanim.face.regions import skin

        return skin(self.mesh, self.landmarks)

    @cached_property
    def slits(self) -> dict[str, np.ndarray]:
        """Slit name (mouth, eye_L, eye_R) -> (V,) bool, True on the lower lip or lid."""
        from faceanim.face.regions import slit_sides

        return slit_sides(self.mesh, self.landmarks)

    @cached_property
    def face_region(self) -> np.ndarray:
        """(V,) bool: the visible face inside the landmark oval."""
        from faceanim.face.regions import face_region

        return face_region(self.mesh, self.landmarks, self.frame)

    @cached_property
    def free_region(self) -> np.ndarray:
        """(V,) bool: what an expression may move (the face grown by a margin, the jaw)."""
        from faceanim.face.regions import free_region

        return free_region(self.mesh, self.landmarks, self.frame)

    @cached_property
    def feature_points(self):
        """The MPEG-4 feature points and FAPU (:class:`~faceanim.face.fdp.FeaturePoints`)."""
        from faceanim.face.fdp import feature_points

        return feature_points(self.mesh, self.landmarks)

    @cached_property
    def landmark_fit(self):
        """The generic head's morphable model fitted to the landmarks alone
        (:func:`~faceanim.face.registration.fit_landmarks`: similarity, weights, residual)."""
        from faceanim.face.registration import fit_landmarks

        return fit_landmarks(self.landmarks)

    @cached_property
    def registration(self):
        """The generic head registered to this face (:class:`~faceanim.face.registration.Registration`):
        its morphable model fitted, then non-rigid ICP onto the surface; the one dense
        correspondence every method uses."""
        from faceanim.face.registration import register

        return register(self)

    @cached_property
    def correspondence(self):
        """Per vertex, the generic head's triangle and barycentric coordinates of its point
        (:func:`~faceanim.face.registration.face_to_head` through :attr:`registration`)."""
        from faceanim.face.registration import face_to_head

        return face_to_head(self, self.registration)

    def view(self, margin: float = VIEW_MARGIN, yaw: float = VIEW_YAW, pitch: float = VIEW_PITCH) -> dict:
        """The camera faceanim shows a face with (keyword arguments of the renderer): framed on the
        face oval with a margin (a full head would render small), turned a little to show depth."""
        from faceanim.face.landmarks import FACE_OVAL

        return {"frame_vertices": self.landmarks[list(FACE_OVAL)], "margin": margin, "yaw": yaw, "pitch": pitch}
