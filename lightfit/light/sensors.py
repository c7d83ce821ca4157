r"""Virtual horizontal quantum sensors in the field: ceptometers at the soil, sensors at a height.

A :class:`Sensor` is an upward-facing horizontal PAR sensor whose reading is the mean over one or
more straight horizontal lines (its *placements*): a line quantum sensor (ceptometer, e.g. the
80 cm Decagon AccuPAR LP-80 or Delta-T SunScan) laid across the rows at several positions of the
measured area, or a sensor at a height inside or above the canopy. The reading is the PAR
arriving on the horizontal sensor surface from the upper hemisphere, per unit horizontal area:

.. math::

    E = \mathrm{DNI}\,\sin^+\beta\,V(x, \omega_\odot) + \pi L(x, \omega),\qquad \omega \sim \cos\theta/\pi

— the direct sun with a shadow ray, and the sky, sun and soil light scattered by the plants
that arrives along cosine-sampled directions, exactly as on a leaf's side
(:class:`~lightfit.light.estimator.SegmentEstimator`, which does the tracing: the sensors
override only where the points are, :meth:`SensorEstimator._layout` and
:meth:`SensorEstimator._place`). Periodic wrapping, scattering orders, frozen BSDF sampling
and paths kept across suns are the segments'.
Consequences that the tests check: a sensor above the canopy reads
:math:`\mathrm{DNI}\sin\beta + \mathrm{DHI}` (the analytic above-canopy sensor,
:func:`lightfit.model.observe.above_canopy_par`), and so does a sensor on the soil of an empty
field; under a canopy of black leaves its direct part is the gap fraction
:math:`\sin\beta\,e^{-G\,\mathrm{LAI}/\sin\beta}` (Beer–Lambert, Monsi & Saeki 1953).

Points: a sensor's K points are spread over its placements by the first quasi-random coordinate
(the placements are stratified, and each line is sampled uniformly along its length); every
point has one (upper) side. Random numbers are keyed by (seed, :data:`SENSOR_KEY0` + sensor index),
apart from every segment's. Sensors are measuring devices, not scene objects: they cast no
shadow and scatter nothing.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from lightfit.errors import InputError, check_integer, check_real
from lightfit.light.backend import owned
from lightfit.light.estimator import DEFAULT_BOUNCES, SegmentEstimator
from lightfit.light.scene import RAY_OFFSET_M, FieldScene
from lightfit.plant.periodic import PeriodicCell

#: Random-stream key of sensor 0 (sensor i: SENSOR_KEY0 + i), above every segment id.
SENSOR_KEY0 = 1 << 40
#: Points per sensor by default: the soil under a canopy is a mosaic of sunflecks, so a sensor
#: needs far more points than a leaf segment; 2048 points on 3 bounces cost ≈ 0.2 % of the main
#: job's evaluations (docs/model.md, "Ceptometer").
DEFAULT_SENSOR_SAMPLES = 2048
#: Length of a ceptometer's sensing bar, m (AccuPAR LP-80: 80 cm, 80 sensors; SunScan: 1 m, 64).
CEPTOMETER_LENGTH_M = 0.8
#: Placements of a ceptometer over the measured area (readings averaged).
CEPTOMETER_PLACEMENTS = 8
#: Height of a sensor "at the soil", m: the ceptometer's bar lies on the ground.
SOIL_HEIGHT_M = 0.0


@dataclass(frozen=True)
class Sensor:
    """An upward-facing horizontal quantum sensor: the mean over straight horizontal lines.

    Attributes:
        name: what it is (``"ceptometer"``, ``"sensor"``), used in results and messages.
        starts_m, ends_m: (P, 3) end points (x east, y north, z up; m) of its P placements; a
            placement with equal ends is a point sensor. Both ends of a line have the same height.
    """

    name: str
    starts_m: tuple
    ends_m: tuple

    def __post_init__(self):
        try:
            a, b = self.lines()
        except (TypeError, ValueError):  # text or ragged end points: numpy's error named no sensor
            raise InputError(
                f"sensor {self.name!r}: end points {self.starts_m!r} … {self.ends_m!r}",
                parameter="sensors",
                expected="(P, 3) numbers, m",
            ) from None
        if a.ndim != 2 or a.shape[1] != 3 or a.shape != b.shape or len(a) == 0:
            raise InputError(
                f"sensor {self.name!r}: end points of shape {a.shape} and {b.shape}",
                parameter="sensors",
                expected="(P, 3) start and end points, P ≥ 1",
            )
        if not (np.isfinite(a).all() and np.isfinite(b).all()):
            raise InputError(f"sensor {self.name!r}: non-finite end points", parameter="sensors", expected="metres")
        if (a[:, 2] < 0).any() or not np.allclose(a[:, 2], b[:, 2], atol=1e-9):
            raise InputError(
                f"sensor {self.name!r}: heights {a[:, 2].tolist()} … {b[:, 2].tolist()}",
                parameter="sensors",
                expected="horizontal lines at heights ≥ 0 m",
            )

    def lines(self) -> tuple[np.ndarray, np.ndarray]:
        """Start and end points, two (P, 3) float arrays, m."""
        return np.asarray(self.starts_m, dtype=np.float64), np.asarray(self.ends_m, dtype=np.float64)

    @property
    def height_m(self) -> float:
        """Mean height of the placements, m."""
        return float(self.lines()[0][:, 2].mean())


def ceptometer(
    area: PeriodicCell,
    *,
    height_m: float = SOIL_HEIGHT_M,
    length_m: float = CEPTOMETER_LENGTH_M,
    placements: int = CEPTOMETER_PLACEMENTS,
    clip: bool = False,
    name: str = "ceptometer",
) -> Sensor:
    """A line sensor laid across the rows at ``placements`` positions of a rectangular ``area``.

    The usual protocol (e.g. the AccuPAR LP-80 manual, Decagon 2014; Sinclair & Muchow 1999 for
    cereals): the bar lies perpendicular to the rows so that it spans whole row spacings, and
    readings at several positions are averaged. Here the bars' centres are spread evenly along
    the rows (stratified, ``(k + ½)/P`` of the area's length) and alternate across them by a
    Kronecker step, so the placements also cover different positions across the rows.

    Args:
        area: the measured area as a rectangle in the row frame (``Field.cell`` for a periodic
            field; :func:`measured_area` for either boundary).
        height_m: height of the bar, m (0: on the soil).
        length_m: bar length, m.
        placements: number of positions averaged.
        clip: shorten the bar to the area's width across the rows (a finite field: the bar stays
            on the measured plants; a periodic one wraps and needs no clipping).
        name: the sensor's name.
    """
    if not isinstance(area, PeriodicCell):  # None stopped on an AttributeError naming size_m
        raise InputError(
            f"area of type {type(area).__name__}", parameter="area", expected="the measured area, e.g. Field.cell"
        )
    # check_integer and check_real: placements=True stopped on a numpy TypeError, a text length or
    # height on Python's, and a negative or NaN height was blamed on "sensors".
    placements = check_integer(placements, "placements", 1, expected="an integer ≥ 1")
    length_m = check_real(length_m, "length_m", 0.0, expected="a bar length ≥ 0 m")
    height_m = check_real(height_m, "height_m", 0.0, expected="a height ≥ 0 m (0: on the soil)")
    A, B = area.size_m
    half = 0.5 * (min(length_m, B) if clip else length_m)
    k = np.arange(placements)
    along = ((k + 0.5) / placements - 0.5) * A
    # Centres across the rows: golden-ratio steps over the width the bar leaves free.
    free = max(B - 2 * half, 0.0) if clip else B
    across = (np.mod(k * 0.6180339887498949, 1.0) - 0.5) * free
    starts = area.to_world(np.column_stack([along, across - half]))
    ends = area.to_world(np.column_stack([along, across + half]))
    z = np.full((placements, 1), float(height_m))
    return Sensor(name, tuple(map(tuple, np.hstack([starts, z]))), tuple(map(tuple, np.hstack([ends, z]))))


def measured_area(field) -> PeriodicCell:
    """The measurement area of a :class:`~lightfit.plant.Field` as a rectangle in the row frame:
    N_along plants × plant spacing along the rows by N_rows rows × row spacing across, centred on the origin
    (the periodic cell itself for a periodic field): :attr:`~lightfit.plant.Field.measured_rectangle`."""
    return field.measured_rectangle


def default_sensors(field, height_m: float = SOIL_HEIGHT_M) -> tuple[Sensor, ...]:
    """The sensors a coupled run renders by default: one ceptometer at ``height_m`` (m; default on
    the soil) over the measured area (:data:`CEPTOMETER_PLACEMENTS` bars of
    :data:`CEPTOMETER_LENGTH_M`, clipped to a finite area)."""
    return (ceptometer(measured_area(field), height_m=height_m, clip=not field.periodic),)


class SensorEstimator(SegmentEstimator):
    """Irradiance on horizontal :class:`Sensor` s: a :class:`SegmentEstimator` whose points lie on
    the sensors' lines (one upper side each) instead of on mesh faces.

    ``render()`` returns an :class:`~lightfit.light.estimator.Irradiance` with one entry per
    sensor (``segment_id`` = :data:`SENSOR_KEY0` + index): ``incident_sun`` per unit DNI,
    ``incident_sky`` per unit DHI (a sensor's reading; the ``absorbed_*`` parts are a leaf's
    absorptance applied to it and mean nothing here), with Monte Carlo standard errors.
    """

    def __init__(
        self,
        field_scene: FieldScene,
        sensors: Sequence[Sensor],
        *,
        samples: int = DEFAULT_SENSOR_SAMPLES,
        bounces: int = DEFAULT_BOUNCES,
        seed: int = 0,
        epsilon_m: float = RAY_OFFSET_M,
    ):
        self.sensors = tuple(sensors)
        if not self.sensors or not all(isinstance(s, Sensor) for s in self.sensors):
            raise InputError(f"sensors={sensors!r}", parameter="sensors", expected="one or more Sensor")
        super().__init__(
            field_scene,
            SENSOR_KEY0 + np.arange(len(self.sensors)),
            samples=samples,
            bounces=bounces,
            seed=seed,
            epsilon_m=epsilon_m,
        )

    def _layout(self, seg: np.ndarray) -> np.ndarray:
        """The sensors' lines as Dr.Jit arrays for :meth:`_place`; ``area_m2`` = 1 (a reading is per
        unit horizontal area)."""
        mi = self.fs.mi
        lines = [s.lines() for s in self.sensors]
        a = np.concatenate([ln[0] for ln in lines])
        b = np.concatenate([ln[1] for ln in lines])
        count = np.array([len(ln[0]) for ln in lines])
        offset = np.cumsum(count) - count
        self._lines = (
            [owned(a[:, c], mi.Float64) for c in range(3)],
            [owned(b[:, c], mi.Float64) for c in range(3)],
            owned(offset, mi.UInt32),
            owned(count, mi.UInt32),
        )
        return np.ones(len(seg))

    def _place(self, si, u):
        """Points on the sensors' lines (m): the first coordinate picks the placement and the
        position along it (stratified over placements); one upper side, no back side."""
        import drjit as dr

        mi = self.fs.mi
        a, b, offset, count = self._lines
        n = dr.gather(mi.UInt32, count, si)
        t = u[0] * mi.Float64(n)
        j = dr.minimum(mi.UInt32(dr.floor(t)), n - 1)
        k = dr.gather(mi.UInt32, offset, si) + j
        frac = t - mi.Float64(j)
        x = []
        for ac, bc in zip(a, b):
            p, q = dr.gather(mi.Float64, ac, k), dr.gather(mi.Float64, bc, k)
            x.append(p + frac * (q - p))
        zero = dr.zeros(mi.Float64, dr.width(t))
        return x, [zero, zero, zero + 1.0], dr.zeros(mi.Bool, dr.width(t))


__all__ = [
    "CEPTOMETER_LENGTH_M",
    "CEPTOMETER_PLACEMENTS",
    "DEFAULT_SENSOR_SAMPLES",
    "SENSOR_KEY0",
    "Sensor",
    "SensorEstimator",
    "ceptometer",
    "default_sensors",
    "measured_area",
]
