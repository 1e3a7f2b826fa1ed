"""The keys of ``descend.json`` and of a descent's site track (what ``hd descend`` writes) as typed
records, and the names of its files.

``hd descend`` (``hdnet.descend``) writes them and ``hd view`` reads ``descend.json`` and the tracks
back (after its own structure check, ``hdnet.view_descent.read_descend``). They are ``TypedDict``: at
run time the dictionaries the files hold, keys in the order hd writes them; for mypy records whose
every key a reader names is checked with its type. A leaf module without PyTorch (``hd view`` reads
these files). docs/user-guide.md ("Deciding during the descent") describes the files.
"""

from __future__ import annotations

from typing import NotRequired, TypedDict

from hdnet.report_json import ThresholdJson
from lidarsim.manifest_json import DemGridJson

__all__ = [
    "RECORD_NAME",
    "TIMING_STEPS",
    "AimJson",
    "DescendInputJson",
    "DescendJson",
    "DescendRunJson",
    "DescentJson",
    "DivertJson",
    "FrameJson",
    "TrackGeoJson",
    "frame_file",
    "is_descend_file",
    "track_file",
]

RECORD_NAME = "descend.json"
TIMING_STEPS = ("registration", "mosaic", "map", "sites")  # the seconds recorded per frame


def frame_file(descent: int, frame: int) -> str:
    """The name of one frame's maps (``descent-KKKKK-frame-NN.npz``)."""
    return f"descent-{descent:05d}-frame-{frame:02d}.npz"


def track_file(descent: int) -> str:
    """The name of one descent's site track (``descent-KKKKK-track.geojson``)."""
    return f"descent-{descent:05d}-track.geojson"


def is_descend_file(name: str) -> bool:
    """True for the names of the files ``hd descend`` writes (its output's own files)."""
    if name == RECORD_NAME:
        return True
    head, _, tail = name.partition("-")
    parts = tail.split("-")
    return head == "descent" and len(parts) >= 2 and parts[0].isdigit() and name.endswith((".npz", ".geojson"))


# A site as ``hdnet.results.SITE_COLUMNS`` name them (rank, x, y in metres, P(safe), ...).
AimJson = dict[str, float | int]


class DivertJson(TypedDict):
    """A change of aim (``hdnet.descent_flight.Divert``): after ``frame``, ``elapsed_s`` seconds after the
    descent's first frame, at ``altitude_m`` metres; ``old`` and ``new`` aims (x, y metres), ``distance_m``
    apart, and why."""

    frame: int
    elapsed_s: float
    altitude_m: float
    old: list[float]
    new: list[float]
    distance_m: float
    reason: str


class FrameJson(TypedDict, total=False):
    """One frame's row: its altitude (metres above the target by the navigation), seconds per step
    (``TIMING_STEPS``), the aim after it, its sites and cell counts, its divert, and ``no_map``: why the
    frame has no map (None: it has one; then the aim is held and it has no sites)."""

    frame: int
    altitude_m: float
    timings_s: dict[str, float]
    aim: AimJson | None
    n_sites: int
    counts: dict[str, int] | None
    divert: DivertJson | None
    no_map: str | None
    registration_fitness: list[float]  # ``registered`` poses only: every frame so far, registered again


class DescentJson(TypedDict):
    """One descent flown: its index and split, its frames, its diverts, the final aim, the median seconds
    per frame and its files (the frames' ``.npz`` and the track)."""

    descent: int
    split: str | None
    frames: list[FrameJson]
    diverts: list[DivertJson]
    final_site: AimJson | None
    median_frame_s: float
    files: list[str]


class DescendRunJson(TypedDict):
    """``run``: the checkpoint that mapped, its dataset and labels (as recorded)."""

    checkpoint: str
    dataset: str | None
    labels: str | None


class DescendInputJson(TypedDict):
    """``input``: the descent build, the frames' noise level (metres), the poses and the mosaic's grid
    (``hdlabels.store.DemSpec.to_entry``)."""

    dataset: str
    sigma_m: float
    poses: str
    dem: DemGridJson


class DescendJson(TypedDict):
    """``descend.json``."""

    software: str
    software_version: str
    run: DescendRunJson
    input: DescendInputJson
    lander: NotRequired[dict[str, float | str]]  # hdlabels.Lander's fields (the aim's footprint)
    settings: dict[str, object]  # hdnet.descend_settings.DescendSettings' fields
    threshold: ThresholdJson
    frame: str
    timing_steps: list[str]
    descents: list[DescentJson]
    seconds: float


class TrackGeoJson(TypedDict):
    """``descent-KKKKK-track.geojson``: a FeatureCollection of a Point per frame with an aim (properties:
    ``frame``, ``altitude_m``, ``diverted`` and the site's columns) and one LineString of the aims in
    order (mosaic-frame metres)."""

    type: str
    features: list[dict[str, object]]
