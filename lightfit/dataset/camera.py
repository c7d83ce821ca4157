"""Cameras of the data scene: pinhole geometry, exposure settings, validation and sweeps.

Coordinates are the field's: x east, y north, z up, metres; the soil is the plane z = 0. A camera
is a pinhole at ``position_m`` looking at ``look_at_m``; ``fov_deg`` is the *horizontal* field of
view. Pixel (row, col) = (0, 0) is the top-left corner of the image.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from lightfit.errors import InputError
from lightfit.plant.periodic import compass_vector

EXPOSURE_MODES = ("leaf", "scene", "fixed")
#: The largest exposure compensation, stops either way: a gain 2^±64 is finite and non-zero in float32.
MAX_EXPOSURE_EV = 64.0
#: Largest image side accepted, pixels: 16 k × 16 k already needs ~3 GB per float RGB image.
MAX_SIDE_PX = 16384


@dataclass(frozen=True)
class Camera:
    """A pinhole camera with its exposure settings.

    Attributes:
        name: file-name stem of its images (letters, digits, ``-`` and ``_``).
        position_m: (x, y, z) of the pinhole, m; z > 0 (above the soil).
        look_at_m: (x, y, z) the optical axis passes through, m.
        up: approximate up direction (need not be orthogonal to the view direction).
        fov_deg: horizontal field of view, degrees, in (0, 180).
        width_px, height_px: image size, pixels.
        exposure_mode: ``"leaf"`` — meter on leaf pixels only: the ``meter_percentile``-th
            percentile of their brightest channel maps to white (the reference paper's advice: expose for
            the leaves so they do not lose information); ``"scene"`` — average metering on all
            pixels: mean luminance maps to 18 % grey (what a consumer camera does; over-lights
            sunlit leaves on dark soil); ``"fixed"`` — a fixed gain of 2^exposure_ev per unit
            radiance (W m⁻² sr⁻¹).
        exposure_ev: exposure compensation, stops (added in every mode).
        meter_percentile: percentile (0, 100] of leaf pixels' brightest channel mapped to white
            in ``leaf`` mode (≈ 100 − percentile % of leaf pixels clip at 0 EV).
    """

    name: str = "cam"
    position_m: tuple[float, float, float] = (0.8, -0.8, 0.7)
    look_at_m: tuple[float, float, float] = (0.0, 0.0, 0.25)
    up: tuple[float, float, float] = (0.0, 0.0, 1.0)
    fov_deg: float = 45.0
    width_px: int = 512
    height_px: int = 512
    exposure_mode: str = "leaf"
    exposure_ev: float = 0.0
    meter_percentile: float = 99.0

    def __post_init__(self):
        for name in ("position_m", "look_at_m", "up"):
            object.__setattr__(self, name, _vec3(getattr(self, name), name))
        _check_name(self.name)
        for name in ("width_px", "height_px"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not 1 <= v <= MAX_SIDE_PX:
                raise InputError(
                    f"camera {self.name!r}: {name}={v!r}",
                    parameter=name,
                    expected=f"an integer number of pixels in [1, {MAX_SIDE_PX}]",
                )
        if not (_finite_number(self.fov_deg) and 0.0 < self.fov_deg < 180.0):
            raise InputError(
                f"camera {self.name!r}: fov_deg={self.fov_deg!r}",
                parameter="fov_deg",
                expected="a horizontal field of view in degrees, strictly between 0 and 180",
            )
        if self.position_m[2] <= 0.0:
            raise InputError(
                f"camera {self.name!r}: position_m={self.position_m} is not above the soil",
                parameter="position_m",
                expected="z > 0 m (the soil is the plane z = 0; from below it the camera sees nothing)",
            )
        view = np.subtract(self.look_at_m, self.position_m)
        if np.linalg.norm(view) < 1e-9:
            raise InputError(
                f"camera {self.name!r}: look_at_m equals position_m {self.position_m}",
                parameter="look_at_m",
                expected="a point different from the camera position",
            )
        if (
            np.linalg.norm(self.up) < 1e-12
            or np.linalg.norm(np.cross(view / np.linalg.norm(view), _unit(self.up))) < 1e-6
        ):
            raise InputError(
                f"camera {self.name!r}: up={self.up} is zero or parallel to the view direction",
                parameter="up",
                expected="a direction not parallel to look_at_m − position_m (tilt it slightly for a nadir view)",
            )
        if self.exposure_mode not in EXPOSURE_MODES:
            raise InputError(
                f"camera {self.name!r}: unknown exposure_mode {self.exposure_mode!r}",
                parameter="exposure_mode",
                expected=" or ".join(EXPOSURE_MODES),
            )
        # bounded: the gain 2^exposure_ev overflowed (an OverflowError traceback after the renders, from
        # about 1024 stops) or became 0 (black images, unsaid)
        if not (_finite_number(self.exposure_ev) and abs(self.exposure_ev) <= MAX_EXPOSURE_EV):
            raise InputError(
                f"camera {self.name!r}: exposure_ev={self.exposure_ev!r}",
                parameter="exposure_ev",
                expected=f"a finite number of stops, −{MAX_EXPOSURE_EV:g} … {MAX_EXPOSURE_EV:g}",
            )
        if not (_finite_number(self.meter_percentile) and 0.0 < self.meter_percentile <= 100.0):
            raise InputError(
                f"camera {self.name!r}: meter_percentile={self.meter_percentile!r}",
                parameter="meter_percentile",
                expected="a percentile in (0, 100]",
            )

    def basis(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Orthonormal (right, up, forward) vectors of the camera frame."""
        fwd = _unit(np.subtract(self.look_at_m, self.position_m))
        right = _unit(np.cross(fwd, self.up))
        return right, np.cross(right, fwd), fwd

    def directions(self, jitter: np.ndarray | None = None) -> np.ndarray:
        """Unit ray directions (H·W, 3), float64, row-major from the top-left pixel.

        Args:
            jitter: (H, W, 2) sub-pixel offsets in [0, 1) (column, row); ``None`` = pixel centres.
        """
        h, w = self.height_px, self.width_px
        rows, cols = np.meshgrid(np.arange(h, dtype=float), np.arange(w, dtype=float), indexing="ij")
        du, dv = (0.5, 0.5) if jitter is None else (jitter[..., 0], jitter[..., 1])
        half = math.tan(math.radians(self.fov_deg) / 2.0)
        x = ((cols + du) / w * 2.0 - 1.0) * half
        y = (1.0 - (rows + dv) / h * 2.0) * half * h / w
        right, up, fwd = self.basis()
        d = fwd + x[..., None] * right + y[..., None] * up
        return (d / np.linalg.norm(d, axis=-1, keepdims=True)).reshape(-1, 3)

    def to_dict(self) -> dict:
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(self).items()}


def _finite_number(v) -> bool:
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool) and math.isfinite(v)


def _unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v)


def _vec3(v, name: str) -> tuple[float, float, float]:
    try:
        a = np.asarray(v, dtype=float)
    except (TypeError, ValueError) as err:
        raise InputError(f"{name}={v!r} is not three numbers", parameter=name, expected="(x, y, z) in metres") from err
    if a.shape != (3,) or not np.isfinite(a).all():
        raise InputError(f"{name}={v!r}", parameter=name, expected="three finite numbers (x, y, z), metres")
    return tuple(float(x) for x in a)


def _check_name(name) -> None:
    ok = isinstance(name, str) and name != "" and all(c.isalnum() or c in "-_" for c in name)
    if not ok:
        raise InputError(
            f"camera name {name!r}", parameter="name", expected="a non-empty name of letters, digits, '-' and '_'"
        )


@dataclass(frozen=True)
class Sweep:
    """Cameras on a circle around the field, all looking at its centre.

    Attributes:
        n: number of cameras (≥ 1), evenly spaced in azimuth starting at ``start_azimuth_deg``
            (compass, clockwise from north).
        distance_m: horizontal distance from the field centre, m (> 0).
        elevation_deg: elevation of the line of sight above the horizontal, degrees, in (0, 90).
        target_height_m: height of the point looked at, m (default: half the canopy height).
    """

    n: int = 4
    distance_m: float = 1.0
    elevation_deg: float = 35.0
    start_azimuth_deg: float = 180.0
    target_height_m: float | None = None
    camera: dict = field(default_factory=dict)

    def __post_init__(self):
        if isinstance(self.n, bool) or not isinstance(self.n, (int, np.integer)) or self.n < 1:
            raise InputError(f"sweep n={self.n!r}", parameter="n", expected="an integer number of cameras ≥ 1")
        if not (_finite_number(self.distance_m) and self.distance_m > 0):
            raise InputError(
                f"sweep distance_m={self.distance_m!r}",
                parameter="distance_m",
                expected="a positive distance in metres",
            )
        if not (_finite_number(self.elevation_deg) and 0.0 < self.elevation_deg < 90.0):
            raise InputError(
                f"sweep elevation_deg={self.elevation_deg!r}",
                parameter="elevation_deg",
                expected="degrees strictly between 0 and 90",
            )


def camera_sweep(sweep: Sweep, centre_m=(0.0, 0.0), canopy_height_m: float = 0.5) -> list[Camera]:
    """The cameras of a :class:`Sweep` around ``centre_m`` (x, y in m).

    Extra ``Camera`` fields come from ``sweep.camera``.
    """
    tz = sweep.target_height_m if sweep.target_height_m is not None else canopy_height_m / 2.0
    el = math.radians(sweep.elevation_deg)
    cams = []
    for k in range(sweep.n):
        east, north = compass_vector(sweep.start_azimuth_deg + 360.0 * k / sweep.n)
        pos = (
            centre_m[0] + sweep.distance_m * east,
            centre_m[1] + sweep.distance_m * north,
            tz + sweep.distance_m * math.tan(el),
        )
        cams.append(
            Camera(
                **{
                    **sweep.camera,
                    "name": f"sweep{k:03d}",
                    "position_m": pos,
                    "look_at_m": (centre_m[0], centre_m[1], tz),
                }
            )
        )
    return cams


def load_cameras(path: str | Path) -> list[Camera]:
    """Read a camera list: a JSON list of :class:`Camera` field dicts (or one such dict); each needs
    ``position_m``, the others default to :class:`Camera`'s (``look_at_m`` the field's centre at
    0.25 m); unknown keys are errors."""
    path = Path(path)
    try:
        raw = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError as err:
        raise InputError("camera file not found", file=path, expected="a JSON list of camera objects") from err
    except json.JSONDecodeError as err:
        raise InputError(f"not valid JSON: {err}", file=path, expected="a JSON list of camera objects") from err
    except UnicodeDecodeError as err:  # another encoding (UTF-16 from some editors): a traceback before
        raise InputError(f"not UTF-8 text: {err}", file=path, expected="a JSON list of camera objects") from err
    except OSError as err:  # a folder, no permission
        raise InputError(
            f"cannot be read ({err.strerror})", file=path, expected="a JSON list of camera objects"
        ) from err
    if isinstance(raw, dict):
        raw = [raw]
    if not isinstance(raw, list) or not raw:
        raise InputError("no cameras", file=path, expected="a non-empty JSON list of camera objects")
    known = set(Camera.__dataclass_fields__)
    for i, c in enumerate(raw):
        if not isinstance(c, dict):
            raise InputError(f"camera #{i} is {type(c).__name__}", file=path, expected="a JSON object")
        bad = set(c) - known
        if bad:
            raise InputError(
                f"camera #{i}: unknown key(s) {sorted(bad)}", file=path, expected=f"keys among {sorted(known)}"
            )
        if "position_m" not in c:  # where the camera is: no default stands in for it
            raise InputError(
                f"camera #{i} has no position_m", file=path, column="position_m", expected="[x, y, z] in metres"
            )
    try:
        cams = [Camera(**{"name": f"cam{i:03d}", **c}) for i, c in enumerate(raw)]
        check_unique_names(cams)
    except InputError as err:  # the cameras' own checks, restated for the file they came from
        raise err.in_file(path) from err
    return cams


def check_unique_names(cams: list[Camera]) -> None:
    """Image files are named after cameras, so names must be unique."""
    names = [c.name for c in cams]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise InputError(f"duplicate camera name(s) {dup}", parameter="name", expected="a unique name per camera")
