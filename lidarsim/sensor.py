"""Flash-LiDAR geometry: the ray bundle of a pinhole detector and the sensor attitude.

Frames
------
*Sensor frame*: ``x`` along detector columns (left to right), ``y`` along detector rows (top to
bottom), ``z`` along the boresight, towards the terrain.

*Scan frame* (the frame points are stored in): origin at the sensor's nadir point, ``x`` east,
``y`` north, ``z`` up, metres. At nadir attitude the sensor's ``x`` is east, its ``y`` is south
and its boresight is down, so detector row 0 looks at the northern edge: images are north-up.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass, fields
from typing import Any

import numpy as np

from hdcore.storage import attr_float, attr_int
from lidarsim import defaults, limits
from lidarsim.errors import LidarsimError

# Rotation taking sensor-frame vectors to the scan frame at nadir attitude (columns are the
# sensor axes in the scan frame): x_s -> east, y_s -> south, z_s -> down.
NADIR_ATTITUDE: np.ndarray = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]], dtype=np.float64)


@dataclass(frozen=True)
class SensorConfig:
    """A flash-LiDAR detector: resolution, field of view and detector defects.

    Attributes:
        rows: detector rows (pixels).
        cols: detector columns (pixels).
        fov_x_deg: full horizontal field of view, degrees (across columns).
        fov_y_deg: full vertical field of view, degrees (across rows).
        focal_length_m: focal length, metres (recorded only: the FOV alone shapes the rays).
        dead_elements: number of detector elements that never return (NaN, status ``dead``).
        damaged_elements: number of elements with a large range error in the noisy ranges.
        damaged_error_m: 1-sigma of the extra Gaussian range error of damaged elements, metres.
    """

    rows: int = defaults.DETECTOR_ROWS
    cols: int = defaults.DETECTOR_COLS
    fov_x_deg: float = defaults.FOV_DEG
    fov_y_deg: float = defaults.FOV_DEG
    focal_length_m: float = defaults.FOCAL_LENGTH_M
    dead_elements: int = defaults.DEAD_ELEMENTS
    damaged_elements: int = defaults.DAMAGED_ELEMENTS
    damaged_error_m: float = 5.0

    def __post_init__(self) -> None:
        if self.rows < 2 or self.cols < 2:
            raise LidarsimError(f"detector must be at least 2x2 pixels, got {self.rows}x{self.cols}")
        if max(self.rows, self.cols) > limits.MAX_DETECTOR_PX:
            raise LidarsimError(
                f"detector of {self.rows}x{self.cols} pixels exceeds hd's maximum of {limits.MAX_DETECTOR_PX} "
                "pixels per side (--resolution)"
            )
        for name in ("fov_x_deg", "fov_y_deg"):
            value = getattr(self, name)
            if not limits.FOV_DEG.contains(value):
                raise LidarsimError(f"{name} must be in {limits.FOV_DEG.interval()} degrees, got {value}")
        n_pixels = self.rows * self.cols
        if self.dead_elements < 0 or self.damaged_elements < 0:
            raise LidarsimError("dead and damaged element counts must be >= 0")
        if self.dead_elements + self.damaged_elements > n_pixels:
            raise LidarsimError(
                f"dead + damaged elements ({self.dead_elements + self.damaged_elements}) "
                f"exceed the detector's {n_pixels} pixels"
            )
        if not (self.damaged_error_m > 0.0 and math.isfinite(self.damaged_error_m)):
            raise LidarsimError(f"damaged_error_m must be > 0 metres, got {self.damaged_error_m}")

    @property
    def half_diagonal_rad(self) -> float:
        """Angle between the boresight and a detector corner (of the pixel edge), radians."""
        tx = math.tan(math.radians(self.fov_x_deg) / 2.0)
        ty = math.tan(math.radians(self.fov_y_deg) / 2.0)
        return math.atan(math.hypot(tx, ty))

    def to_attrs(self) -> dict[str, int | float]:
        """Flat attribute dictionary (HDF5/JSON friendly)."""
        return {f"sensor_{k}": v for k, v in asdict(self).items()}

    @classmethod
    def from_attrs(cls, attrs: Mapping[str, object]) -> SensorConfig:
        """The sensor a scan shard was made with, from its ``sensor_*`` attributes (``to_attrs``).

        Raises:
            LidarsimError: a missing or non-numeric attribute, or values ``SensorConfig`` refuses.
        """
        values: dict[str, Any] = {}  # SensorConfig's keywords: each an int or a float, checked by it
        for f in fields(cls):
            key = f"sensor_{f.name}"
            if key not in attrs:
                raise LidarsimError(f"the scan shard's attributes lack {key}")
            raw = attrs[key]
            try:
                values[f.name] = attr_int(raw) if f.type in (int, "int") else attr_float(raw)
            except (TypeError, ValueError) as exc:
                raise LidarsimError(f"the scan shard's attribute {key} is not a number: {raw!r}") from exc
        return cls(**values)


def ray_directions(sensor: SensorConfig) -> np.ndarray:
    """Unit ray directions through the detector pixel centres, in the sensor frame.

    Pixel centres are spaced evenly on the image plane (a pinhole camera): pixel ``(i, j)`` has
    image-plane coordinates ``(tan(fov_x/2)·u_j, tan(fov_y/2)·v_i)`` with
    ``u_j = (2j + 1)/cols − 1`` and ``v_i = (2i + 1)/rows − 1``.

    Returns:
        float64 array (rows, cols, 3) of unit vectors; the ray parameter along them is the range
        in metres.
    """
    tx = math.tan(math.radians(sensor.fov_x_deg) / 2.0)
    ty = math.tan(math.radians(sensor.fov_y_deg) / 2.0)
    u = (2.0 * np.arange(sensor.cols) + 1.0) / sensor.cols - 1.0
    v = (2.0 * np.arange(sensor.rows) + 1.0) / sensor.rows - 1.0
    uu, vv = np.meshgrid(u * tx, v * ty)
    d = np.stack([uu, vv, np.ones_like(uu)], axis=-1)
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    return d


def footprint_corners(fov_x_deg: float, fov_y_deg: float, attitudes: np.ndarray, positions: np.ndarray) -> np.ndarray:
    """Where the detector's four outer corners look on the scan frame's reference plane (z = 0):
    each scan's ground footprint as a quadrilateral, metres in the scan frame.

    The corner rays pass through the image-plane corners ``(±tan(fov_x/2), ±tan(fov_y/2), 1)``
    (sensor frame), turned to the scan frame by each scan's ``attitudes`` (N, 3, 3) and cast from
    its ``positions`` (N, 3), e.g. ``(0, 0, altitude)``. Over flat ground at nadir attitude this is
    the square ``±altitude·tan(fov/2)``; tilt and jitter skew it. A corner ray that does not reach
    the plane (pointing at or above the horizon) gives NaN.

    Returns:
        float64 (N, 4, 2): x, y of the corners in the order (−,−), (+,−), (+,+), (−,+) of the
        image-plane axes, a closed ring when drawn in that order.
    """
    tx = math.tan(math.radians(fov_x_deg) / 2.0)
    ty = math.tan(math.radians(fov_y_deg) / 2.0)
    corners = np.array([[-tx, -ty, 1.0], [tx, -ty, 1.0], [tx, ty, 1.0], [-tx, ty, 1.0]])
    rays = np.einsum("nij,kj->nki", np.asarray(attitudes, np.float64), corners)  # (N, 4, 3), scan frame
    origin = np.asarray(positions, np.float64)[:, None, :]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(rays[..., 2] < 0.0, -origin[..., 2] / rays[..., 2], np.nan)
    return origin[..., :2] + t[..., None] * rays[..., :2]


def corner_directions(sensor: SensorConfig, attitude: np.ndarray) -> np.ndarray:
    """Unit directions of the detector's four outer corners, turned by ``attitude`` (3, 3) to the
    scan frame: float64 (4, 3). Every ray of the detector (a pixel centre or a footprint's sub-ray)
    lies inside the pyramid they span."""
    tx = math.tan(math.radians(sensor.fov_x_deg) / 2.0)
    ty = math.tan(math.radians(sensor.fov_y_deg) / 2.0)
    corners = np.array([[-tx, -ty, 1.0], [tx, -ty, 1.0], [tx, ty, 1.0], [-tx, ty, 1.0]])
    corners /= np.linalg.norm(corners, axis=-1, keepdims=True)
    return corners @ np.asarray(attitude, dtype=np.float64).T


def rotation_x(angle_rad: float) -> np.ndarray:
    """Right-handed rotation matrix about the x axis, angle in radians."""
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rotation_y(angle_rad: float) -> np.ndarray:
    """Right-handed rotation matrix about the y axis, angle in radians."""
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rotation_z(angle_rad: float) -> np.ndarray:
    """Right-handed rotation matrix about the z axis, angle in radians."""
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def sensor_attitude(tilt_deg: float = 0.0, jitter_rad: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> np.ndarray:
    """Rotation from the sensor frame to the scan frame.

    Args:
        tilt_deg: off-nadir tilt of the boresight, degrees, a rotation about the sensor x axis
            (positive tilts the boresight towards the north).
        jitter_rad: small attitude errors (about sensor x, y, z), radians, applied after the tilt.

    Returns:
        float64 (3, 3) matrix ``R`` with ``d_scan = R @ d_sensor``.
    """
    jx, jy, jz = jitter_rad
    return NADIR_ATTITUDE @ rotation_x(math.radians(tilt_deg)) @ rotation_x(jx) @ rotation_y(jy) @ rotation_z(jz)


def footprint_half_width_m(
    sensor: SensorConfig, altitude_m: float, tilt_deg: float = 0.0, jitter_deg: float = 0.0
) -> float:
    """Conservative half-width of the square, axis-aligned ground footprint around the nadir point, metres.

    Over flat ground at ``altitude_m`` below the sensor: the edge ray of the wider field of view,
    widened by the tilt and a 3-sigma attitude jitter, and by the yaw of a 3-sigma jitter that
    turns the square footprint (``cos + sin`` of the yaw angle).
    """
    half_fov = math.radians(max(sensor.fov_x_deg, sensor.fov_y_deg) / 2.0)
    three_sigma = math.radians(3.0 * jitter_deg)
    angle = half_fov + math.radians(abs(tilt_deg)) + three_sigma
    if angle >= math.radians(80.0):
        raise LidarsimError(
            f"field of view, tilt and jitter reach {math.degrees(angle):.0f} deg off nadir; "
            "the footprint would be unbounded"
        )
    return altitude_m * math.tan(angle) * (math.cos(three_sigma) + math.sin(three_sigma))
