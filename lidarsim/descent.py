"""Descents: K frames flown from a start altitude down to an end altitude toward one target point.

A descent has a target point on the terrain (chosen by the planner as single scans' positions are,
``lidarsim.trajectory``). Its frame ``k`` of ``K`` flies at

    h_k = START + (END - START) k / (K - 1)        (frame 0 the highest)

metres above the target's reference height (the mean terrain height around the target), on a
straight line through the target at ``approach_deg`` A from the vertical, coming from the azimuth
``phi`` (degrees clockwise from north, drawn per descent from the stream ``(seed, DESCENT_AZIMUTH,
descent)`` when A > 0). Every frame of a descent shares one **scan frame**: origin at the target
(its x, y and the reference height), x east, y north, z up. In it the sensor is at

    s_k = (h_k tan A sin phi, h_k tan A cos phi, h_k)

and the boresight points at the origin: the attitude is ``Rz(-(phi + 180 deg)) @
sensor_attitude(A, jitter)`` (``lidarsim.sensor``: the tilt A about the sensor's x axis, then the
usual attitude jitter), so the image's top row looks along the approach, beyond the target. A
vertical descent (A = 0) keeps the nadir attitude, north up, and draws no azimuth.

The navigation estimate of each frame's pose is ``lidarsim.navigation``'s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from lidarsim import defaults, limits
from lidarsim.errors import LidarsimError
from lidarsim.navigation import NavigationError
from lidarsim.sensor import SensorConfig, footprint_half_width_m, rotation_z, sensor_attitude
from lidarsim.streams import Purpose, stream


@dataclass(frozen=True)
class DescentConfig:
    """How each descent flies (module docstring).

    Attributes:
        frames: K, frames per descent (at least 2).
        altitude_start_m: altitude of frame 0 above the target's reference height, metres.
        altitude_end_m: altitude of frame K - 1, metres (lower than the start).
        approach_deg: angle of the approach path from the vertical, degrees (0 = vertical).
        nav: the navigation error model.
    """

    frames: int
    altitude_start_m: float = defaults.DESCENT_ALTITUDE_START_M
    altitude_end_m: float = defaults.DESCENT_ALTITUDE_END_M
    approach_deg: float = defaults.APPROACH_DEG
    nav: NavigationError = field(default_factory=NavigationError)

    def __post_init__(self) -> None:
        k = self.frames
        if isinstance(k, bool) or not isinstance(k, int) or not 2 <= k <= limits.MAX_DESCENT_FRAMES:
            raise LidarsimError(
                f"--descent-frames must be an integer in [2, {limits.MAX_DESCENT_FRAMES}] (0: single frames), got {k!r}"
            )
        start, end = self.altitude_start_m, self.altitude_end_m
        for value in (start, end):
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not limits.ALTITUDE_M.contains(value):
                bound = limits.ALTITUDE_M.interval()
                raise LidarsimError(f"--descent-altitudes must be two numbers of metres in {bound}, got {value!r}")
        if not start > end:
            raise LidarsimError(
                f"--descent-altitudes {start:g}:{end:g} does not descend; give START:END with START > END (1000:250)"
            )
        if not limits.APPROACH_DEG.contains(self.approach_deg):
            raise LidarsimError(
                f"--approach-deg must be in {limits.APPROACH_DEG.interval()} degrees, got {self.approach_deg!r}"
            )

    def altitude_m(self, frame: int) -> float:
        """Altitude of frame ``frame`` above the target's reference height, metres."""
        return self.altitude_start_m + (self.altitude_end_m - self.altitude_start_m) * frame / (self.frames - 1)

    def azimuth_deg(self, seed: int, descent_index: int) -> float:
        """Direction the approach of descent ``descent_index`` comes from, degrees clockwise from north
        (uniform in [0, 360) from the stream ``(seed, DESCENT_AZIMUTH, descent)``); 0 for a vertical descent."""
        if self.approach_deg == 0.0:
            return 0.0
        return 360.0 * float(stream(seed, Purpose.DESCENT_AZIMUTH, descent_index).random())

    def reach_m(self, sensor: SensorConfig, jitter_deg: float) -> float:
        """Half-width of the square around the target that holds every frame's footprint over flat
        ground, metres (the widest is frame 0's, at the start altitude ``h``).

        Vertical: ``footprint_half_width_m`` at ``h`` with the jitter's 1-sigma times sqrt(2), so that a
        3-sigma jitter about both tilt axes at once is covered. Along an approach A: the image's rows
        run along the approach, so a ray ``(p, q, 1)`` of the image plane (``|p| <= tan a_x``, ``|q| <=
        tan a_y``) meets the ground ``h (tan(A + atan q) - tan A)`` beyond the target along the track
        and ``h p cos(atan q) / cos(A + atan q)`` across it; both grow toward the far corners, so every
        ground point lies within ``R = h hypot(tan(A + a_y) - tan A, tan a_x cos a_y / cos(A + a_y))``
        of the target, whatever the approach's azimuth. ``a_x``, ``a_y`` are the half fields of view
        widened by a 3-sigma jitter about each of the three axes (a ray moves by at most the sum,
        ``9 sigma``, divided by the cosine of the widened half-angle for its projection).

        Raises:
            LidarsimError: the rays would reach 80 degrees off nadir (the footprint is unbounded).
        """
        h = self.altitude_start_m
        if self.approach_deg == 0.0:
            return footprint_half_width_m(sensor, h, 0.0, math.sqrt(2.0) * jitter_deg)
        a = math.radians(self.approach_deg)
        moved = math.radians(9.0 * jitter_deg)
        widest = math.radians(max(sensor.fov_x_deg, sensor.fov_y_deg) / 2.0) + moved
        widen = moved / math.cos(widest)
        a_x = math.radians(sensor.fov_x_deg / 2.0) + widen
        a_y = math.radians(sensor.fov_y_deg / 2.0) + widen
        if a + a_y >= math.radians(80.0):
            raise LidarsimError(
                f"an approach of {self.approach_deg:g} deg with the field of view and jitter reaches "
                f"{math.degrees(a + a_y):.0f} deg off nadir; the footprint would be unbounded (lower --approach-deg)"
            )
        along = math.tan(a + a_y) - math.tan(a)
        across = math.tan(a_x) * math.cos(a_y) / math.cos(a + a_y)
        return h * math.hypot(along, across)

    def to_attrs(self) -> dict[str, object]:
        """The shard attributes of a descent build: ``descent_frames``, ``descent_altitude_start_m``,
        ``descent_altitude_end_m``, ``descent_approach_deg`` and the ``nav_*`` of the error model."""
        return {
            "descent_frames": int(self.frames),
            "descent_altitude_start_m": float(self.altitude_start_m),
            "descent_altitude_end_m": float(self.altitude_end_m),
            "descent_approach_deg": float(self.approach_deg),
            **self.nav.to_attrs(),
        }


def frame_pose(
    descent: DescentConfig, frame: int, azimuth_deg: float, jitter_rad: tuple[float, float, float] = (0.0, 0.0, 0.0)
) -> tuple[np.ndarray, np.ndarray]:
    """The true pose of frame ``frame`` in the descent's scan frame (origin at the target on its
    reference height): ``(sensor_position, attitude)``, float64 (3,) metres and (3, 3) (sensor
    frame to scan frame), as in the module docstring."""
    h = descent.altitude_m(frame)
    a = math.radians(descent.approach_deg)
    phi = math.radians(azimuth_deg)
    offset = h * math.tan(a)
    position = np.array([offset * math.sin(phi), offset * math.cos(phi), h], dtype=np.float64)
    attitude = sensor_attitude(descent.approach_deg, jitter_rad)
    if descent.approach_deg != 0.0:
        attitude = rotation_z(-(phi + math.pi)) @ attitude
    return position, attitude
