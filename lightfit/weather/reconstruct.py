"""Reconstructed forcing for a day whose measured series is not available offline.

The only on-record measurement of 2016-04-20 at Selhausen is one chamber point
(12:13:48 local time, PAR 1549.31 µmol m⁻² s⁻¹, Tair 19.2 °C; docs/design.md §5). Everything else in
:func:`reconstruct_day` is physics for the site and date plus stated assumptions; the result
is labelled ``provenance = "reconstructed"`` and must never be called measured.
"""

from __future__ import annotations

import ast
from dataclasses import asdict, dataclass

import numpy as np
import pandas as pd
import pvlib

from lightfit.weather import units
from lightfit.weather.solar import SELHAUSEN, Site, add_solar, pvlib_deprecations_quiet


@dataclass(frozen=True)
class Anchor:
    """A single recorded observation the reconstruction must reproduce.

    Attributes:
        time_local: timestamp as recorded, in ``tz``.
        tz: timezone of ``time_local``. Chamber loggers run on local civil time (CEST in
            April), hence ``Europe/Berlin``; this is an assumption.
        par_umol_m2_s: PAR at the anchor, µmol m⁻² s⁻¹.
        tair_c: air temperature at the anchor, °C.
    """

    time_local: str = "2016-04-20 12:13:48"
    tz: str = "Europe/Berlin"
    par_umol_m2_s: float = 1549.31
    tair_c: float = 19.2

    @property
    def time_utc(self) -> pd.Timestamp:
        return pd.Timestamp(self.time_local, tz=self.tz).tz_convert("UTC")

    @classmethod
    def of(cls, attrs: dict) -> Anchor | None:
        """The anchor a reconstructed series was scaled to, from its attributes (``metadata``'s
        ``anchor`` line as the reader gives it, a dict or its text), or ``None``."""
        meta = attrs.get("metadata")
        a = (meta.get("anchor") if isinstance(meta, dict) else None) or attrs.get("anchor")
        if not a:
            return None
        return cls(**(a if isinstance(a, dict) else ast.literal_eval(str(a))))


@dataclass(frozen=True)
class DayAssumptions:
    """Assumed course of the quantities that the anchor does not fix.

    Attributes:
        clear_sky_model: pvlib clear-sky model (Ineichen & Perez 2002 with the monthly
            Linke turbidity climatology shipped with pvlib).
        tair_amplitude_k: half the diurnal air temperature range, K (a clear April day in the
            Lower Rhine basin has a 10–14 K range; 6 K → 12 K range).
        tair_peak_hours_after_noon: hours after solar noon at which air temperature peaks
            (typically 2–3 h).
        dawn_rh: relative humidity (0–1) at the temperature minimum; vapour pressure is held
            constant through the day, so RH falls as the air warms.
        co2_ppm: constant CO2 mole fraction. 2016 background ≈ 404 ppm (NOAA global annual
            mean); well-mixed daytime surface air over a crop is slightly below. The
            reference paper did not use measured CO2 either.
        pressure_kpa: ``None`` → standard atmosphere at the site altitude (pvlib ``alt2pres``).
    """

    clear_sky_model: str = "ineichen"
    tair_amplitude_k: float = 6.0
    tair_peak_hours_after_noon: float = 2.5
    dawn_rh: float = 0.90
    co2_ppm: float = 400.0
    pressure_kpa: float | None = None


def solar_noon_utc(date: str, site: Site = SELHAUSEN) -> pd.Timestamp:
    """Time of solar transit (UTC) on ``date`` at ``site``, from pvlib's SPA."""
    with pvlib_deprecations_quiet():
        tr = pvlib.solarposition.sun_rise_set_transit_spa(
            pd.DatetimeIndex([pd.Timestamp(date, tz="UTC") + pd.Timedelta("12h")]),
            site.latitude_deg,
            site.longitude_deg,
        )
    return pd.Timestamp(tr["transit"].iloc[0]).tz_convert("UTC")


def reconstruct_day(
    date: str = "2016-04-20",
    *,
    site: Site = SELHAUSEN,
    anchor: Anchor = Anchor(),
    assumptions: DayAssumptions = DayAssumptions(),
    step: str = "10min",
) -> pd.DataFrame:
    r"""Reconstruct a day's forcing (00:00–23:50 UTC) anchored on one recorded point.

    - Global radiation: clear-sky GHI for the site and date scaled by one factor
      :math:`k = \mathrm{PAR}_{anchor} / (2.285\,\mathrm{GHI}_{cs}(t_{anchor}))`, i.e. a uniform
      attenuation through the day, so PAR equals the anchor exactly at the anchor time.
    - Diffuse radiation: the clear-sky model's own diffuse part, scaled by the same k, so that the
      light model splits this clear day as its clear-sky model does (:func:`add_solar` with the
      split 'diffuse') rather than by a decomposition model fitted to all skies (Erbs, which at
      this day's clearness index gives a PAR-weighted diffuse share of ≈ 0.40 against the
      clear sky's ≈ 0.26; docs/weather.md).
    - PAR = 0.50 × 4.57 µmol J⁻¹ × GHI.
    - Air temperature: :math:`T(t) = \bar T + A\cos(2\pi (t - t_{peak})/24\,\mathrm h)` with
      :math:`\bar T` chosen so that :math:`T(t_{anchor}) = T_{anchor}`.
    - Humidity: constant vapour pressure :math:`e = RH_{dawn}\,e_s(T_{min})`, RH = e/e_s(T).
    - CO2 and pressure constant (see :class:`DayAssumptions`).

    Returns a contract series with solar columns and ``attrs``: ``provenance =
    "reconstructed"``, the anchor, the assumptions and the scale factor ``k``.
    """
    times = pd.date_range(pd.Timestamp(date, tz="UTC"), periods=int(pd.Timedelta("1D") / pd.Timedelta(step)), freq=step)
    loc = pvlib.location.Location(site.latitude_deg, site.longitude_deg, altitude=site.altitude_m)
    t_anchor = anchor.time_utc
    with pvlib_deprecations_quiet():
        clear = loc.get_clearsky(times.append(pd.DatetimeIndex([t_anchor])), model=assumptions.clear_sky_model)
    k = anchor.par_umol_m2_s / float(units.par_from_ghi(clear["ghi"].iloc[-1]))
    ghi, diffuse = k * clear["ghi"].iloc[:-1], k * clear["dhi"].iloc[:-1]

    t_peak = solar_noon_utc(date, site) + pd.Timedelta(hours=assumptions.tair_peak_hours_after_noon)
    day_s = 86400.0
    phase = lambda t: 2 * np.pi * ((t - t_peak) / pd.Timedelta(seconds=1)) / day_s  # noqa: E731
    a = assumptions.tair_amplitude_k
    t_mean = anchor.tair_c - a * np.cos(phase(t_anchor))
    tair = t_mean + a * np.cos(phase(times))
    e = assumptions.dawn_rh * units.saturation_vapour_pressure_alduchov_kpa(t_mean - a)
    rh = e / units.saturation_vapour_pressure_alduchov_kpa(tair)
    p = assumptions.pressure_kpa or float(units.kpa_from_pa(pvlib.atmosphere.alt2pres(site.altitude_m)))

    df = pd.DataFrame(
        {
            "ghi_w_m2": ghi.to_numpy(),
            "par_umol_m2_s": units.par_from_ghi(ghi.to_numpy()),
            "diffuse_w_m2": diffuse.to_numpy(),
            "tair_c": np.asarray(tair, dtype=float),
            "rh": np.asarray(rh, dtype=float),
            "pair_kpa": np.full(len(times), p),
            "co2_ppm": np.full(len(times), assumptions.co2_ppm),
        },
        index=times.rename("time_utc"),
    )
    df.attrs = {
        "source": "lightfit.weather.reconstruct_day",
        "format": "lightfit",
        "provenance": "reconstructed",
        "timezone_assumed": "UTC",
        "anchor": asdict(anchor),
        "assumptions": asdict(assumptions),
        "clear_sky_scale": k,
        "qc": [],
        "site": site,
    }
    return add_solar(df, site)
