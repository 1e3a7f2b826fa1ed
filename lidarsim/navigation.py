"""The navigation error of a descent: what the vehicle believes its pose to be, frame by frame.

A descent's frames are placed in the map with the navigation system's estimate of each pose, which
is the true pose plus an error with two parts, each drawn 1-sigma per map axis (x east, y north,
z up) from its own seeded stream (``lidarsim.streams``):

- a **bias**, drawn once per descent: ``b = (P n_1, P n_2, P n_3)`` for the position (metres) and
  ``(Pa n_4, Pa n_5, Pa n_6)`` for the attitude (a rotation vector, radians), ``n ~ N(0, 1)`` from
  the stream ``(seed, NAV_BIAS, descent)``;
- a **random walk**: at each frame ``j >= 1`` an increment ``(W m_1, W m_2, W m_3)`` and
  ``(Wa m_4, Wa m_5, Wa m_6)``, ``m ~ N(0, 1)`` from the stream ``(seed, NAV_WALK, descent, j)``.

Frame ``k``'s error is ``e_k = b + sum_{j=1..k} increment_j`` (frame 0 has the bias only), so its
variance per axis is ``P^2 + k W^2``. The estimated position is the true one plus the position
error (in the map axes, which are the scan frame's); the estimated attitude is
``Rot(theta_k) @ R_true``, with ``Rot`` the rotation by the vector ``theta_k`` (Rodrigues'
formula, exact) about the map axes. With every sigma 0 the estimate is the true pose exactly.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from hdcore.setting import check, setting
from lidarsim import defaults, limits
from lidarsim.errors import LidarsimError
from lidarsim.streams import Purpose, stream


@dataclass(frozen=True)
class NavigationError:
    """The navigation error model of a descent (all 1-sigma per map axis; 0 = none). Each field's
    help, unit, default and range is its metadata (``hdcore.setting``): ``hd build-dataset``'s
    options, a recipe's ``[build]`` keys (``lidarsim.recipe.BuildSettings``) and the checks here are
    made from it.

    Attributes:
        position_sigma_m: the position bias drawn once per descent, metres.
        position_walk_m: the position increment added at each frame after the first, metres.
        attitude_sigma_deg: the attitude bias (a small rotation about the map axes), degrees.
        attitude_walk_deg: the attitude increment at each frame after the first, degrees.
    """

    position_sigma_m: float = setting(
        defaults.NAV_POSITION_SIGMA_M,
        "A descent's navigation error: 1-sigma per map axis of its position bias, drawn once per descent",
        unit="metres",
        bound=limits.NAV_POSITION_M,
        flag="--nav-position-sigma",
    )
    position_walk_m: float = setting(
        defaults.NAV_POSITION_WALK_M,
        "A descent's navigation error: 1-sigma per map axis of the position increment added at each frame "
        "after the first (a random walk)",
        unit="metres",
        bound=limits.NAV_POSITION_M,
        flag="--nav-position-walk",
    )
    attitude_sigma_deg: float = setting(
        defaults.NAV_ATTITUDE_SIGMA_DEG,
        "A descent's navigation error: 1-sigma per map axis of its attitude bias (a small rotation), drawn "
        "once per descent",
        unit="degrees",
        bound=limits.NAV_ATTITUDE_DEG,
        flag="--nav-attitude-sigma",
    )
    attitude_walk_deg: float = setting(
        defaults.NAV_ATTITUDE_WALK_DEG,
        "A descent's navigation error: 1-sigma per map axis of the attitude increment at each frame after the "
        "first (a random walk)",
        unit="degrees",
        bound=limits.NAV_ATTITUDE_DEG,
        flag="--nav-attitude-walk",
    )

    def __post_init__(self) -> None:
        check(self, LidarsimError)

    @property
    def is_perfect(self) -> bool:
        """True when every sigma is 0: the estimate is the true pose."""
        return not (self.position_sigma_m or self.position_walk_m or self.attitude_sigma_deg or self.attitude_walk_deg)

    def to_attrs(self) -> dict[str, float]:
        """The shard attributes ``nav_position_sigma_m``, ``nav_position_walk_m``,
        ``nav_attitude_sigma_deg``, ``nav_attitude_walk_deg``."""
        return {f"nav_{k}": float(v) for k, v in asdict(self).items()}


@dataclass(frozen=True)
class DescentNavErrors:
    """The navigation errors of the K frames of one descent.

    Attributes:
        position_m: float64 (K, 3) position error of each frame, map axes, metres.
        rotation_rad: float64 (K, 3) attitude error of each frame, a rotation vector about the map
            axes, radians.
    """

    position_m: np.ndarray
    rotation_rad: np.ndarray

    def estimate(self, frame: int, sensor_position: np.ndarray, attitude: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The navigation estimate of frame ``frame``'s pose: ``(sensor_position + e_k,
        Rot(theta_k) @ attitude)``, float64 (3,) and (3, 3), in the frame's scan frame."""
        position = np.asarray(sensor_position, dtype=np.float64) + self.position_m[frame]
        attitude = np.asarray(attitude, dtype=np.float64)
        if not self.rotation_rad[frame].any():  # no attitude error: the true attitude, bit for bit
            return position, attitude.copy()
        return position, rotation_from_vector(self.rotation_rad[frame]) @ attitude


def descent_nav_errors(model: NavigationError, seed: int, descent_index: int, frames: int) -> DescentNavErrors:
    """The navigation errors of descent ``descent_index``'s ``frames`` frames (module docstring).

    Every stream is drawn whatever the sigmas (a sigma of 0 multiplies its draws by 0), so one
    descent's errors depend on its seed and index only: the same whatever the worker or shard.
    """
    if frames < 1:
        raise LidarsimError(f"a descent has at least one frame, got {frames}")
    position_scale = np.array([model.position_sigma_m, model.position_walk_m], dtype=np.float64)
    attitude_scale = np.radians(np.array([model.attitude_sigma_deg, model.attitude_walk_deg], dtype=np.float64))
    draws = np.empty((frames, 6), dtype=np.float64)
    draws[0] = stream(seed, Purpose.NAV_BIAS, descent_index).standard_normal(6)
    for j in range(1, frames):
        draws[j] = stream(seed, Purpose.NAV_WALK, descent_index, j).standard_normal(6)
    # row 0 the bias, rows j >= 1 the increments; their running sum is each frame's error
    scale_p = np.where(np.arange(frames) == 0, position_scale[0], position_scale[1])[:, None]
    scale_a = np.where(np.arange(frames) == 0, attitude_scale[0], attitude_scale[1])[:, None]
    return DescentNavErrors(
        position_m=np.cumsum(draws[:, :3] * scale_p, axis=0),
        rotation_rad=np.cumsum(draws[:, 3:] * scale_a, axis=0),
    )


def rotation_from_vector(theta: np.ndarray) -> np.ndarray:
    """The rotation matrix of the rotation vector ``theta`` (axis times angle, radians), by Rodrigues'
    formula ``I + sin(a) K + (1 - cos(a)) K^2`` (``K`` the cross-product matrix of the unit axis); the
    identity exactly for a zero vector."""
    theta = np.asarray(theta, dtype=np.float64)
    angle = math.sqrt(float(theta @ theta))
    if angle == 0.0:
        return np.eye(3)
    kx, ky, kz = theta / angle
    k = np.array([[0.0, -kz, ky], [kz, 0.0, -kx], [-ky, kx, 0.0]])
    return np.eye(3) + math.sin(angle) * k + (1.0 - math.cos(angle)) * (k @ k)


def estimated_map_points(
    points: np.ndarray,
    origin_map: np.ndarray,
    sensor_position: np.ndarray,
    sensor_attitude: np.ndarray,
    nav_sensor_position: np.ndarray,
    nav_sensor_attitude: np.ndarray,
) -> np.ndarray:
    """Where the navigation system places stored points in the map: for each point ``p`` (scan
    frame, metres) ``origin_map + nav_sensor_position + nav_sensor_attitude @ sensor_attitude.T @
    (p - sensor_position)`` (docs/shard-format.md). With a perfect estimate this is ``p + origin_map`` (to rounding).

    Args:
        points: (..., 3) points in the scan frame (float32 as stored, or float64), metres.
        origin_map, sensor_position, nav_sensor_position: (3,) of the frame, metres.
        sensor_attitude, nav_sensor_attitude: (3, 3) of the frame.

    Returns:
        float64 (..., 3) map coordinates, metres (NaN where the point is NaN).
    """
    p = np.asarray(points, dtype=np.float64) - np.asarray(sensor_position, dtype=np.float64)
    rotation = np.asarray(nav_sensor_attitude, dtype=np.float64) @ np.asarray(sensor_attitude, dtype=np.float64).T
    return p @ rotation.T + (np.asarray(origin_map, dtype=np.float64) + np.asarray(nav_sensor_position))
