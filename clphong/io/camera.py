"""The camera of a frame from its OpenEXR ``worldToCamera`` header attribute.

OpenEXR's standard attribute ``worldToCamera`` (type ``M44f``) is the matrix
that takes world-space points into the renderer's camera space, whose origin
is the camera (OpenEXR "Standard Attributes"). OpenEXR matrices follow
Imath's row-vector convention, ``p_cam = p_world · M``, so the translation is
the last row. The eye is the camera-space origin taken back to the world:

    eye = (0, 0, 0, 1) · M⁻¹,

the last row of ``M⁻¹``. Only the eye is needed by a perspective Phong shader
(``v = normalize(eye − P)``), so the camera space's own axis conventions (the
OpenEXR/RenderMan left-handed +z-forward space, or an OpenGL-style −z-forward
one) do not matter.

Some writers store the transpose (column vectors, translation in the last
column). An affine matrix says which it is: its projective part is
``(0, 0, 0, 1)`` in the last column (row vectors) or in the last row (column
vectors); :func:`eye_from_matrix` accepts both and rejects anything else.

World up axis
-------------
clphong's world, in which the scene's lights and the G-buffer positions are
given, is Y-up (as in the samples). ``up="y"`` (the default) says that the
matrix is written in that same world. ``up="z"`` says that the matrix is
written in a Z-up world (Blender, 3ds Max, Unreal) while positions and lights
are Y-up; its eye is then rotated into the Y-up world by the usual
conversion ``(x, y, z)_Zup → (x, z, −y)_Yup`` (a −90° rotation about x).
"""

from __future__ import annotations

import os
from collections.abc import Mapping

import numpy as np

from ..core.errors import GBufferError
from ..model.scene import CAMERA_UP_AXES, Camera

__all__ = ["UP_AXES", "WORLD_TO_CAMERA", "Z_UP_TO_Y_UP", "world_to_camera", "eye_from_matrix",
           "camera_from_attributes", "camera_from_matrix", "resolve_camera"]

#: Name of the OpenEXR standard attribute.
WORLD_TO_CAMERA = "worldToCamera"
#: Valid ``up`` values: the up axis of the world the matrix is written in (the scene's camera.up).
UP_AXES = CAMERA_UP_AXES
#: Rotation taking a Z-up world point to the Y-up world (column vectors):
#: (x, y, z) → (x, z, −y). An exact signed permutation, so no rounding.
Z_UP_TO_Y_UP = np.array([[1.0, 0.0, 0.0],
                         [0.0, 0.0, 1.0],
                         [0.0, -1.0, 0.0]])


def world_to_camera(attributes: Mapping[str, object]) -> np.ndarray | None:
    """The ``worldToCamera`` matrix of a header as a (4, 4) float64 array, or None.

    Parameters
    ----------
    attributes : mapping
        Header attributes, e.g. ``GBuffer.attributes`` (OpenImageIO gives a
        matrix as 16 numbers in row-major order).

    Returns
    -------
    numpy.ndarray or None
        The matrix as stored (row-major), or None when the header has none.
    """
    value = attributes.get(WORLD_TO_CAMERA) if attributes else None
    if value is None:
        return None
    arr = np.asarray(value, dtype=np.float64)
    if arr.size != 16:
        raise GBufferError(f"{WORLD_TO_CAMERA}: expected a 4x4 matrix, got {arr.size} values")
    return arr.reshape(4, 4)


def eye_from_matrix(M: np.ndarray, *, up: str = "y", source: str = "<frame>") -> np.ndarray:
    """The camera position in clphong's (Y-up) world, from a world-to-camera matrix.

    Parameters
    ----------
    M : array_like
        (4, 4) world-to-camera matrix, row-vector (Imath/OpenEXR) or
        column-vector layout (detected from where its ``(0, 0, 0, 1)`` is).
    up : {"y", "z"}
        Up axis of the world the matrix is written in (see module docstring).
    source : str
        File name for messages.

    Returns
    -------
    numpy.ndarray
        (3,) float64 eye position.

    Raises
    ------
    GBufferError
        A non-finite, projective (not affine) or singular matrix, or a bad
        ``up``; the message names ``source`` and the attribute.
    """
    if up not in UP_AXES:
        raise GBufferError(f"{source}: camera up axis {up!r} is not one of {', '.join(map(repr, UP_AXES))}")
    M = np.asarray(M, dtype=np.float64).reshape(4, 4)
    where = f"{source}: {WORLD_TO_CAMERA}"
    if not np.all(np.isfinite(M)):
        raise GBufferError(f"{where}: the matrix has NaN or Inf entries")
    unit_w = np.array([0.0, 0.0, 0.0, 1.0])
    if np.array_equal(M[:, 3], unit_w):
        rows = M                        # Imath: p · M, translation in the last row
    elif np.array_equal(M[3, :], unit_w):
        rows = M.T                      # column vectors: M · p, translation in the last column
    else:
        raise GBufferError(f"{where}: not an affine transform (neither its last column nor its last "
                           f"row is 0, 0, 0, 1): {_fmt(M)}; is it a projection (worldToNDC)?")
    A = rows[:3, :3]
    t = rows[3, :3]
    # A rigid camera transform has |det A| = 1 (with scale s, s³); a determinant
    # this small relative to the entries means no unique eye.
    scale = float(np.max(np.abs(A)))
    det = float(np.linalg.det(A))
    if scale == 0.0 or abs(det) <= 1e-12 * scale ** 3:
        raise GBufferError(f"{where}: singular matrix (det {det:.3g}) has no camera position: {_fmt(M)}")
    # eye · A + t = 0  ⇒  eye = −t · A⁻¹ (row vectors), solved in float64.
    eye = np.linalg.solve(A.T, -t)
    if up == "z":
        eye = Z_UP_TO_Y_UP @ eye
    return eye


def camera_from_matrix(M: np.ndarray, *, up: str = "y", source: str = "<frame>"):
    """A perspective :class:`~clphong.model.scene.Camera` at the eye of ``M`` (see :func:`eye_from_matrix`)."""
    eye = eye_from_matrix(M, up=up, source=source)
    return Camera(type="perspective", position=tuple(float(x) for x in eye))


def camera_from_attributes(attributes: Mapping[str, object], *, up: str = "y",
                           source: str = "<frame>", scene_source: str = "<scene>"):
    """The perspective camera of a frame's header (``worldToCamera``).

    Raises
    ------
    GBufferError
        When the header has no ``worldToCamera``: the message names the
        frame and the scene and says how to fix it.
    """
    M = world_to_camera(attributes)
    if M is None:
        raise GBufferError(f"{source}: no {WORLD_TO_CAMERA} attribute, and {scene_source} has no "
                           "[camera]; add a [camera] table to the scene, or write the camera "
                           f"matrix into the EXR header as {WORLD_TO_CAMERA}")
    return camera_from_matrix(M, up=up, source=source)


def resolve_camera(scene, attributes: Mapping[str, object] | None = None, *,
                   world_to_camera_matrix=None, source: str = "<frame>"):
    """``scene`` with a concrete camera for one frame.

    A scene whose camera is ``type = "metadata"`` (or that has no
    ``[camera]``) takes the frame's ``worldToCamera`` (or
    ``world_to_camera_matrix`` when given, e.g. for numpy input); any other
    scene is returned unchanged.
    """
    import dataclasses

    cam = scene.camera
    if cam.type != "metadata":
        return scene
    up = getattr(cam, "up", None) or "y"
    if world_to_camera_matrix is not None:
        camera = camera_from_matrix(world_to_camera_matrix, up=up, source=source)
    else:
        camera = camera_from_attributes(attributes or {}, up=up, source=source,
                                        scene_source=os.fspath(scene.source))
    return dataclasses.replace(scene, camera=camera)


def _fmt(M: np.ndarray) -> str:
    return "[" + "; ".join(" ".join(f"{v:.6g}" for v in row) for row in M) + "]"
