"""Sun position and the direct/diffuse split of global radiation, via pvlib.

The site (coordinates, altitude) is a :class:`~lightfit.weather.site.Site`; the default is the
Selhausen field minirhizotron facility (:data:`~lightfit.weather.site.SELHAUSEN`).
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pvlib

from lightfit.errors import InputError
from lightfit.weather.site import SELHAUSEN, Site
from lightfit.weather.units import par_from_ghi

SPLIT_MODELS = ("erbs", "boland")


def solar_position(times: pd.DatetimeIndex, site: Site = SELHAUSEN) -> pd.DataFrame:
    """Apparent solar elevation and azimuth (degrees) at tz-aware ``times``.

    Uses pvlib's NREL SPA (Reda & Andreas 2004, Solar Energy 76, 577), with refraction.
    Azimuth is clockwise from north.
    """
    if times.tz is None:
        raise InputError(
            "timestamps are timezone-naive", column="time", expected="tz-aware timestamps (lightfit uses UTC)"
        )
    sp = pvlib.solarposition.get_solarposition(times, site.latitude_deg, site.longitude_deg, altitude=site.altitude_m)
    return pd.DataFrame({"sun_elevation_deg": sp["apparent_elevation"], "sun_azimuth_deg": sp["azimuth"]}, index=times)


def split_direct_diffuse(ghi_w_m2: pd.Series, sun_elevation_deg: pd.Series, model: str = "erbs") -> pd.DataFrame:
    r"""Split global horizontal irradiance into direct normal and diffuse horizontal parts.

    Models: ``"erbs"`` (Erbs, Klein & Duffie 1982, Solar Energy 28, 293) and ``"boland"``
    (Boland, Ridley & Brown 2008, Renewable Energy 33, 575), both from the clearness index.
    Closure holds exactly: GHI = DNI·sin(elevation) + DHI. With the sun below the horizon all
    radiation is diffuse.
    """
    if model not in SPLIT_MODELS:
        raise InputError(
            f"unknown direct/diffuse split model {model!r}", column="split_model", expected=" or ".join(SPLIT_MODELS)
        )
    zenith = 90.0 - sun_elevation_deg
    times = ghi_w_m2.index
    if model == "erbs":
        out = pvlib.irradiance.erbs(ghi_w_m2, zenith, times)
    else:
        out = pvlib.irradiance.boland(ghi_w_m2, zenith, times)
    sin_el = np.sin(np.radians(sun_elevation_deg.clip(lower=0.0)))
    dni = out["dni"].fillna(0.0).clip(lower=0.0).where(sun_elevation_deg > 0.0, 0.0)
    # pvlib caps zenith at 87° for the split; enforce closure so the light model sees exactly GHI.
    dhi = (ghi_w_m2 - dni * sin_el).clip(lower=0.0)
    dni = dni.where(dhi > 0.0, ghi_w_m2 / sin_el.where(sin_el > 0, np.inf))
    return pd.DataFrame({"dni_w_m2": dni, "dhi_w_m2": dhi}, index=times)


def add_solar(df: pd.DataFrame, site: Site | None = None, split_model: str = "erbs") -> pd.DataFrame:
    """Add the derived contract columns: sun angles, DNI/DHI and (if absent) PAR from GHI.

    If only PAR was measured, global radiation is estimated as PAR / (0.50 × 4.57 µmol J⁻¹)
    so that the split can run; either estimate is recorded in ``attrs["qc"]``.
    """
    site = site or df.attrs.get("site") or SELHAUSEN
    out = df.copy()
    out.attrs = dict(df.attrs)
    qc = list(out.attrs.get("qc", []))
    k = float(par_from_ghi(1.0))
    if "par_umol_m2_s" not in out.columns:
        out["par_umol_m2_s"] = par_from_ghi(out["ghi_w_m2"])
        qc.append(
            {
                "kind": "derived",
                "column": "par_umol_m2_s",
                "count": len(out),
                "detail": f"PAR estimated from global radiation × {k:.3f} µmol J⁻¹ (0.50 × 4.57)",
            }
        )
    if "ghi_w_m2" not in out.columns:
        out["ghi_w_m2"] = out["par_umol_m2_s"] / k
        qc.append(
            {
                "kind": "derived",
                "column": "ghi_w_m2",
                "count": len(out),
                "detail": f"global radiation estimated from PAR / {k:.3f} µmol J⁻¹",
            }
        )
    sp = solar_position(out.index, site)
    out["sun_elevation_deg"] = sp["sun_elevation_deg"]
    out["sun_azimuth_deg"] = sp["sun_azimuth_deg"]
    split = split_direct_diffuse(out["ghi_w_m2"], out["sun_elevation_deg"], split_model)
    out["dni_w_m2"], out["dhi_w_m2"] = split["dni_w_m2"], split["dhi_w_m2"]
    out.attrs["qc"] = qc
    out.attrs["site"] = site
    out.attrs["split_model"] = split_model
    return out
