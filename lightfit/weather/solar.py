"""Sun position and the direct/diffuse split of global radiation, via pvlib.

The site (coordinates, altitude) is a :class:`~lightfit.weather.site.Site`; the default is the
Selhausen field minirhizotron facility (:data:`~lightfit.weather.site.SELHAUSEN`).
"""

from __future__ import annotations

import contextlib
import warnings

import numpy as np
import pandas as pd
import pvlib

from lightfit.errors import InputError
from lightfit.weather import timestamps
from lightfit.weather.site import SELHAUSEN, Site
from lightfit.weather.units import PAR_FRACTION, PAR_PER_GHI_UMOL_J, UMOL_PER_JOULE_PAR, par_from_ghi

#: How global radiation is split into its direct and diffuse parts: two decomposition models of the
#: clearness index, or the series' own diffuse radiation (``diffuse_w_m2``: a shaded pyranometer's, an
#: SPN1's, or a clear-sky reconstruction's).
SPLIT_MODELS = ("erbs", "boland", "diffuse")
#: A diffuse column may exceed global radiation by this factor plus
#: :data:`DIFFUSE_OVER_GLOBAL_W_M2` (two instruments' calibrations, a shadow band's correction; under
#: overcast both read the same sky) before a step counts as an error rather than a rounding.
DIFFUSE_OVER_GLOBAL_FACTOR = 1.15
DIFFUSE_OVER_GLOBAL_W_M2 = 10.0
#: The diffuse share of global radiation that a diffuse column must reach at some step with
#: global radiation above :data:`RATIO_MIN_GHI_W_M2`: the clearest skies keep ≈ 0.1 (Rayleigh
#: scattering and aerosols; more at a low sun), so a column that never reaches 0.05 is in the wrong
#: unit (kW m⁻²) or is not diffuse radiation.
DIFFUSE_MIN_SHARE = 0.05
#: A series' diffuse columns, in the order the split ``"diffuse"`` takes them: diffuse PAR (a BF5's,
#: FLUXNET's PPFD_DIF), which is the canopy's own band, then diffuse global radiation.
DIFFUSE_COLUMNS = ("par_diffuse_umol_m2_s", "diffuse_w_m2")
#: Measured PAR ÷ global radiation a series may have, µmol J⁻¹ (median over steps with global
#: radiation above :data:`RATIO_MIN_GHI_W_M2`). Sunlight gives ≈ 2.0–2.3 (Meek et al. 1984, Agron.
#: J. 76, 939: 2.04; McCree 1972 with a PAR share of 0.45–0.50: 2.06–2.29); outside these bounds a
#: unit or clock slip is likelier than the sky.
PAR_PER_GHI_BOUNDS = (1.5, 3.0)
RATIO_MIN_GHI_W_M2 = 50.0
#: Measured radiation must reach this share of clear sky at some step with the sun above
#: :data:`CLEAR_SKY_MIN_ELEVATION_DEG`, else its unit is wrong. A thick overcast lets through
#: 10–20 % of clear-sky global radiation, rain under a storm deck ≈ 5 %; the threshold is the
#: *largest* share over all such steps of a series, so a whole day would have to stay below 2 %,
#: a factor ≥ 2.5 under the darkest sky, while a unit slip is off by ≈ 1000× (kW m⁻² written
#: under W m⁻², mol for µmol: ≈ 0.1 %). Clear sky is Haurwitz's (1945; pvlib), which needs only
#: the sun's zenith; its error against turbidity-based models (tens of percent at most) is far
#: inside that margin.
CLEAR_SKY_MIN_FRACTION = 0.02
CLEAR_SKY_MIN_ELEVATION_DEG = 20.0


@contextlib.contextmanager
def pvlib_deprecations_quiet():
    """Within it, pvlib's own use of pandas APIs that pandas deprecates (pvlib 0.16 reads
    ``DatetimeIndex.dayofyear``, a ``Pandas4Warning`` under pandas 3.1) warns nothing: a user cannot
    act on it, and under ``-W error`` (``PYTHONWARNINGS=error``) it stopped every run at the forcing.
    Only warnings that pvlib's modules raise are silenced, and only here."""
    with warnings.catch_warnings():
        for category in (DeprecationWarning, FutureWarning):
            warnings.filterwarnings("ignore", category=category, module=r"pvlib\.")
        yield


def solar_position(times: pd.DatetimeIndex, site: Site = SELHAUSEN) -> pd.DataFrame:
    """Apparent solar elevation and azimuth (degrees) at tz-aware ``times``, and the true (geometric,
    unrefracted) elevation ``sun_true_elevation_deg`` that decomposition models take
    (:func:`split_direct_diffuse`).

    Uses pvlib's NREL SPA (Reda & Andreas 2004, Solar Energy 76, 577), with refraction for the
    standard pressure at the site's altitude and 12 °C (pvlib's default; not the series' own air).
    Azimuth is clockwise from north.
    """
    if times.tz is None:
        raise InputError(
            "timestamps are timezone-naive", column="time", expected="tz-aware timestamps (lightfit uses UTC)"
        )
    with pvlib_deprecations_quiet():
        sp = pvlib.solarposition.get_solarposition(
            times, site.latitude_deg, site.longitude_deg, altitude=site.altitude_m
        )
    return pd.DataFrame(
        {
            "sun_elevation_deg": sp["apparent_elevation"],
            "sun_azimuth_deg": sp["azimuth"],
            "sun_true_elevation_deg": sp["elevation"],
        },
        index=times,
    )


def check_split_model(model, models=SPLIT_MODELS, where: str = "split_model") -> str:
    """``model`` if it is one of ``models`` (:data:`SPLIT_MODELS` or a part of it), else InputError
    naming ``where`` (the option, or a file's metadata line)."""
    if model not in models:
        raise InputError(f"unknown direct/diffuse split model {model!r}", parameter=where, expected=" or ".join(models))
    return model


#: Boland, Scott & Luther's (2001) logistic fits (a, b) by the series' averaging interval (minutes).
BOLAND_COEFFS = {15: (8.645, 0.613), 60: (7.997, 0.586)}


def boland_coeffs(times: pd.DatetimeIndex, interval: pd.Timedelta | None = None) -> tuple[float, float]:
    """Boland's (a, b) for a series with timestamps ``times`` whose values are means over ``interval``
    (``None``: instants, or not known): the 15-minute fit for intervals up to 30 min, the hourly fit
    for longer ones (:data:`BOLAND_COEFFS`). The fits differ by the averaging of the data they were
    fitted to, not by how far apart the values lie: 10-min means sampled every hour are 10-min
    means. Without an interval the step stands for it (a single step: the 15-minute fit)."""
    if interval is not None:
        minutes = pd.Timedelta(interval) / pd.Timedelta(minutes=1)
    else:
        minutes = pd.Series(times).diff().median() / pd.Timedelta(minutes=1) if len(times) > 1 else 15.0
    return BOLAND_COEFFS[15 if minutes <= 30 else 60]


def split_direct_diffuse(
    ghi_w_m2: pd.Series,
    sun_elevation_deg: pd.Series,
    model: str = "erbs",
    true_elevation_deg: pd.Series | None = None,
    interval: pd.Timedelta | None = None,
) -> pd.DataFrame:
    r"""Split global horizontal irradiance into direct normal and diffuse horizontal parts.

    Models: ``"erbs"`` (Erbs, Klein & Duffie 1982, Solar Energy 28, 293; fitted to hourly data)
    and ``"boland"`` (the logistic diffuse fraction 1 / (1 + exp(a (k_t − b))) of Boland, Scott &
    Luther 2001, Environmetrics 12, 103), both from the clearness index k_t. Boland et al. fitted
    (a, b) per averaging interval: (8.645, 0.613) for 15-minute and (7.997, 0.586) for hourly data;
    series of means over up to 30 min take the first, longer means the second, by their averaging
    ``interval`` (:func:`boland_coeffs`; ``None``: by the step).
    The models take the clearness index from the extraterrestrial irradiance on a horizontal plane
    at the true (unrefracted) solar zenith, as they were fitted (pvlib's ``zenith``):
    ``true_elevation_deg`` (:func:`solar_position`'s ``sun_true_elevation_deg``; default
    ``sun_elevation_deg``). Their DHI is kept and the beam comes from the apparent sun
    ``sun_elevation_deg``, where the canopy sees it: DNI = (GHI − DHI) / sin(elevation), so closure
    holds exactly, GHI = DNI·sin(elevation) + DHI. With the sun below the horizon all radiation is
    diffuse. A negative GHI (a dark offset, which the readers clamp but a series built in code may
    keep) is no light, as in :func:`split_from_diffuse`: DNI = DHI = 0, not a negative beam or sky.
    """
    check_split_model(model, ("erbs", "boland"))
    ghi_w_m2 = ghi_w_m2.astype(float).clip(lower=0.0)
    zenith = 90.0 - (sun_elevation_deg if true_elevation_deg is None else true_elevation_deg)
    times = ghi_w_m2.index
    with pvlib_deprecations_quiet():
        if model == "erbs":
            out = pvlib.irradiance.erbs(ghi_w_m2, zenith, times)
        else:
            a, b = boland_coeffs(times, interval)
            out = pvlib.irradiance.boland(ghi_w_m2, zenith, times, a_coeff=a, b_coeff=b)
    # pvlib's DHI closes with its own (true) zenith and is all of GHI beyond 87°; the rest is the
    # beam, along the apparent sun, so that the light model sees exactly GHI.
    dhi = np.minimum(pd.Series(np.asarray(out["dhi"], float), index=times).fillna(ghi_w_m2), ghi_w_m2).clip(lower=0.0)
    dhi = dhi.where(sun_elevation_deg > 0.0, ghi_w_m2)
    dni = beam_normal(ghi_w_m2 - dhi, sun_elevation_deg)
    return pd.DataFrame({"dni_w_m2": dni, "dhi_w_m2": dhi}, index=times)


def horizontal_irradiance(dni, dhi, sun_elevation_deg, xp=np):
    r"""Irradiance (or photon flux) on a horizontal plane from its direct-normal and diffuse-horizontal
    parts, in their unit: :math:`\mathrm{DNI} \sin^+\beta + \mathrm{DHI}`, the cosine law for the
    beam (below the horizon it counts 0; e.g. Duffie & Beckman 2013, *Solar Engineering of Thermal
    Processes*, eq. 2.15.1 with a horizontal surface). ``xp``: numpy or ``jax.numpy``."""
    return dni * xp.maximum(xp.sin(xp.deg2rad(sun_elevation_deg)), 0.0) + dhi


def beam_normal(beam_horizontal, sun_elevation_deg):
    r"""Direct-normal irradiance (or photon flux) from the beam on a horizontal plane, in its unit:
    :math:`B / \sin\beta`, the inverse of :func:`horizontal_irradiance`'s cosine law; 0 with the sun
    at or below the horizon (a NaN stays NaN). Series in, Series out."""
    sin_b = np.sin(np.radians(sun_elevation_deg))
    return beam_horizontal / np.where(sin_b > 0, sin_b, np.inf)


def check_diffuse(
    total: pd.Series,
    diffuse: pd.Series,
    sun_elevation_deg: pd.Series,
    *,
    what: str = "global radiation",
    unit: str = "W m⁻²",
    bright: float = RATIO_MIN_GHI_W_M2,
    file=None,
    column: str = "diffuse_w_m2",
    hint: str = "",
) -> None:
    """Refuse a diffuse series that cannot be the diffuse part of ``total`` (``what``, in ``unit``),
    naming ``column``: a missing diffuse value where the sun is up; diffuse above the total ×
    :data:`DIFFUSE_OVER_GLOBAL_FACTOR` + :data:`DIFFUSE_OVER_GLOBAL_W_M2` (in W m⁻², scaled to ``unit`` by
    ``bright`` ÷ :data:`RATIO_MIN_GHI_W_M2`) at two or more steps (swapped columns, other units); a
    diffuse share below :data:`DIFFUSE_MIN_SHARE` at every step where the total exceeds ``bright``
    and over the whole lit series (kW m⁻² under a W m⁻² header, mmol under µmol). ``hint`` ends the
    expectation of the first two errors (e.g. where the total is an estimate)."""
    scale = bright / RATIO_MIN_GHI_W_M2
    total, diffuse = total.astype(float), diffuse.astype(float)
    up = sun_elevation_deg > 0.0
    gap = up & diffuse.isna()  # the totals' gaps are refused before (add_solar)
    if gap.any():
        raise InputError(
            f"{int(gap.sum())} step(s) with the sun up lack its diffuse part (first "
            f"{total.index[gap.to_numpy()][0]:%Y-%m-%d %H:%M} UTC)",
            file=file,
            column=column,
            expected=f"{what} and its diffuse part at every daylight step (fill the gaps, or drop the diffuse column)",
        )
    over = up & (diffuse > DIFFUSE_OVER_GLOBAL_FACTOR * total + scale * DIFFUSE_OVER_GLOBAL_W_M2)
    if over.sum() >= 2:
        i = int(np.argmax((diffuse - total).where(over, -np.inf).to_numpy()))
        raise InputError(
            f"diffuse {diffuse.iloc[i]:.4g} {unit} at {total.index[i]:%Y-%m-%d %H:%M} UTC exceeds {what} "
            f"{total.iloc[i]:.4g} {unit}: {int(over.sum())} steps have more diffuse than {what}",
            file=file,
            column=column,
            expected=f"the diffuse part in {unit}, at most {what} (× {DIFFUSE_OVER_GLOBAL_FACTOR:g} + "
            f"{scale * DIFFUSE_OVER_GLOBAL_W_M2:g} {unit} for two instruments); check the columns are not swapped"
            + hint,
        )
    lit = up & (total > 0)
    high = lit & (total > bright)
    shares = [(diffuse[high] / total[high]).max()] if high.any() else []
    if lit.any():
        shares.append(diffuse[lit].clip(lower=0).sum() / total[lit].sum())
    if shares and max(shares) < DIFFUSE_MIN_SHARE:
        raise InputError(
            f"the diffuse part reaches at most {max(shares):.2%} of {what} over the {int(lit.sum())} lit "
            "steps: the unit is wrong",
            file=file,
            column=column,
            expected=f"the diffuse part in {unit} (≥ {DIFFUSE_MIN_SHARE:.0%} of {what} somewhere: the clearest "
            "sky keeps ≈ 10 %, an overcast one all of it)",
        )


def split_from_diffuse(
    ghi_w_m2: pd.Series,
    diffuse_w_m2: pd.Series,
    sun_elevation_deg: pd.Series,
    site: Site = SELHAUSEN,
    *,
    file=None,
    column: str | None = None,
    ghi_estimated: bool = False,
    check: bool = True,
) -> tuple[pd.DataFrame, dict]:
    r"""Direct normal and diffuse horizontal irradiance from a series' global and diffuse radiation.

    DHI is the series' diffuse radiation, cut to [0, GHI], and DNI closes the balance,
    :math:`\mathrm{DNI} = (\mathrm{GHI} - \mathrm{DHI}) / \sin\beta`, as
    :func:`pvlib.irradiance.dni` takes it near the horizon, where a small difference of two
    instruments over a small sin β would make a beam no sky gives: none beyond 88° zenith, at
    most 1.1 × the clear-sky beam (Ineichen–Perez at ``site``) beyond 80°. What is cut from the beam
    is counted as diffuse, so GHI = DNI sin β + DHI holds exactly. With the sun below the horizon
    all radiation is diffuse.

    Returns the split and the counts of steps cut (``"diffuse_above_global"``, ``"beam_cut"``) for
    the series' quality record. ``ghi_estimated``: global radiation was estimated from PAR (the
    messages say so). ``check``: refuse what :func:`check_diffuse` refuses, naming ``column``
    (default ``diffuse_w_m2``); ``False`` where the diffuse radiation was derived from a checked one.
    """
    # A negative total (a dark offset the readers clamp; a series built in code may keep it) is no
    # light, as a negative PAR is (par_direct_diffuse): the closure below holds for it as 0.
    ghi = ghi_w_m2.astype(float).clip(lower=0.0)
    diffuse = diffuse_w_m2.astype(float)
    up = sun_elevation_deg > 0.0
    if check:
        check_diffuse(
            ghi,
            diffuse,
            sun_elevation_deg,
            what="global radiation (estimated from PAR)" if ghi_estimated else "global radiation",
            file=file,
            column=column or "diffuse_w_m2",
            hint=f" and the PAR per joule the estimate assumes ({PAR_PER_GHI_UMOL_J:.4g} µmol J⁻¹)"
            if ghi_estimated
            else "",
        )
    dhi = diffuse.clip(lower=0.0, upper=ghi).where(up, ghi)
    zenith = 90.0 - sun_elevation_deg
    loc = pvlib.location.Location(site.latitude_deg, site.longitude_deg, altitude=site.altitude_m)
    with pvlib_deprecations_quiet():
        clear = loc.get_clearsky(
            ghi.index,
            model="ineichen",
            solar_position=pd.DataFrame({"apparent_zenith": zenith, "apparent_elevation": sun_elevation_deg}),
        )
    raw = beam_normal(ghi - dhi, sun_elevation_deg)
    dni = pvlib.irradiance.dni(ghi, dhi, zenith, dni_clear=clear["dni"]).fillna(0.0).where(up, 0.0)
    # The closure GHI = DNI sin β + DHI; clipped at 0 and GHI: where the file's diffuse is 0 (a clamped
    # dark offset) and the beam is not cut, rounding leaves ≈ −1e-13 W m⁻², which is no irradiance.
    dhi = (ghi - dni * np.sin(np.radians(sun_elevation_deg.clip(lower=0.0)))).clip(lower=0.0, upper=ghi)
    counts = {
        "diffuse_above_global": int((up & (diffuse > ghi)).sum()),
        "beam_cut": int((up & (dni < raw - 1e-9)).sum()),
    }
    return pd.DataFrame({"dni_w_m2": dni, "dhi_w_m2": dhi}, index=ghi.index), counts


def par_direct_diffuse(dni_w_m2, dhi_w_m2, sun_elevation_deg, par_umol_m2_s=None) -> tuple[np.ndarray, np.ndarray]:
    r"""Direct-normal and diffuse-horizontal PAR photon flux, µmol m⁻² s⁻¹, for the light model.

    The horizontal PAR is the series' PAR sensor's where it has one,

    .. math::
        \mathrm{PAR}^h_t = k_t\,\mathrm{GHI}_t,\quad k_t = \frac{\mathrm{PAR}_t}{\mathrm{GHI}_t},\quad
        \mathrm{GHI}_t = \mathrm{DNI}_t \sin\beta_t + \mathrm{DHI}_t

    (GHI by the split's closure), so the canopy is lit with the measured PAR at every step with
    light. Without a PAR series (``None``) k = 0.50 × 4.57 µmol J⁻¹
    (:func:`~lightfit.weather.units.par_from_ghi`); where :func:`add_solar` derived PAR from global
    radiation, or global radiation from PAR, k is that same constant. A PAR reading ≤ 0 (a sensor
    offset at dawn) where GHI > 0 gives no light rather than negative light.

    The diffuse fraction of PAR follows from global radiation's, k_d = DHI / GHI, by
    :func:`par_diffuse_fraction` (Spitters et al. 1986): higher under a clear, blue sky, and
    without the circumsolar part, which comes from around the sun and goes with the beam for the
    light model's sky without a circumsolar peak. Then
    DHI^PAR = k_d^PAR PAR^h and DNI^PAR = (1 − k_d^PAR) PAR^h / sin β.

    Raises:
        InputError: a step with light whose PAR is not a number.
    """
    dni = np.asarray(dni_w_m2, dtype=np.float64)
    dhi = np.asarray(dhi_w_m2, dtype=np.float64)
    el = np.asarray(sun_elevation_deg, dtype=np.float64)
    ghi = horizontal_irradiance(dni, dhi, el)
    lit = ghi > 0
    k = np.full_like(ghi, PAR_PER_GHI_UMOL_J)
    if par_umol_m2_s is not None:
        par = np.asarray(par_umol_m2_s, dtype=np.float64)
        if np.isnan(par[lit]).any():
            bad = np.flatnonzero(lit & np.isnan(par))
            raise InputError(
                f"PAR is missing at {bad.size} step(s) with global radiation (first: step {bad[0]})",
                column="par_umol_m2_s",
                expected="a PAR value wherever DNI or DHI is above 0 (fill or drop those steps)",
            )
        np.divide(np.maximum(par, 0.0), ghi, out=k, where=lit)
    par_h = np.where(lit, k * ghi, 0.0)
    kd_par = par_diffuse_fraction(np.divide(dhi, ghi, out=np.ones_like(ghi), where=lit), el)
    return beam_normal((1.0 - kd_par) * par_h, el), kd_par * par_h


def par_diffuse_fraction(global_diffuse_fraction, sun_elevation_deg) -> np.ndarray:
    r"""Diffuse fraction of PAR from that of global radiation k_d at sun elevation β (Spitters,
    Toussaint & Goudriaan 1986, Agric. For. Meteorol. 38, 217, eqs. 9–10):

    .. math::
        k_d^{PAR} = \frac{[1 + 0.3\,(1 - k_d^2)]\,k_d}{1 + (1 - k_d^2)\cos^2(90° - \beta)\cos^3\beta}

    The numerator is the blue sky's larger share of PAR (Rayleigh scattering; up to 1.3× under a
    clear sky, 1× under overcast), the denominator removes the circumsolar part (Klucher's 1979
    anisotropy term: it removes up to 16 % of the diffuse, at β ≈ 39°), which the light model's sky (uniform or
    CIE overcast, no circumsolar peak) would otherwise spread over the hemisphere. Evaluated by
    pvlib (:func:`pvlib.irradiance.diffuse_par_spitters`, documented there for daily totals at the
    daily mean zenith), here per step with the step's β, as the formula's β is the sun's elevation
    at an instant. At k_d = 1 (overcast, or the sun below the horizon) it is 1; it lies in [0, 1].
    """
    kd = np.clip(np.asarray(global_diffuse_fraction, dtype=np.float64), 0.0, 1.0)
    el = np.asarray(sun_elevation_deg, dtype=np.float64)
    return np.asarray(pvlib.irradiance.diffuse_par_spitters(90.0 - el, kd), dtype=np.float64)


def global_diffuse_fraction(par_diffuse_fraction_, sun_elevation_deg) -> np.ndarray:
    """The diffuse fraction of global radiation whose PAR fraction (:func:`par_diffuse_fraction`,
    Spitters et al. 1986) is ``par_diffuse_fraction_`` at sun elevation β, degrees: its inverse,
    by bisection (the relation rises monotonically from 0 to 1 on [0, 1]; 50 halvings, 1e-15)."""
    target = np.clip(np.asarray(par_diffuse_fraction_, dtype=np.float64), 0.0, 1.0)
    el = np.broadcast_to(np.asarray(sun_elevation_deg, dtype=np.float64), target.shape)
    lo, hi = np.zeros_like(target), np.ones_like(target)
    for _ in range(50):
        mid = 0.5 * (lo + hi)
        below = par_diffuse_fraction(mid, el) < target
        lo, hi = np.where(below, mid, lo), np.where(below, hi, mid)
    return 0.5 * (lo + hi)


def check_par_per_ghi(par_umol_m2_s: pd.Series, ghi_w_m2: pd.Series, file=None) -> float:
    """Median measured PAR ÷ global radiation (µmol J⁻¹) over steps with global radiation above
    :data:`RATIO_MIN_GHI_W_M2`; refused outside :data:`PAR_PER_GHI_BOUNDS` (NaN: too few such steps),
    naming ``file`` (the series' source) where given."""
    bright = (ghi_w_m2 > RATIO_MIN_GHI_W_M2) & par_umol_m2_s.notna()
    lo, hi = PAR_PER_GHI_BOUNDS
    if not bright.any():
        # No step to take the ratio at: fine at night or under a dark sky, not with bright PAR,
        # where PAR / GHI would exceed its bound at the brightest step.
        par_max = float(par_umol_m2_s.max())
        if par_max > hi * RATIO_MIN_GHI_W_M2:
            raise InputError(
                f"PAR reaches {par_max:.4g} µmol m⁻² s⁻¹ while global radiation never exceeds "
                f"{RATIO_MIN_GHI_W_M2:g} W m⁻² (at most {float(ghi_w_m2.max()):.3g}): PAR / global radiation "
                f"is above {hi:g} µmol J⁻¹",
                file=file,
                column="par_umol_m2_s/ghi_w_m2",
                expected="global radiation in W m⁻² (kW m⁻² reads 1000× too small) and PAR in µmol m⁻² s⁻¹, "
                f"{lo:g}–{hi:g} µmol J⁻¹ apart",
            )
        return float("nan")
    ratio = float((par_umol_m2_s[bright] / ghi_w_m2[bright]).median())
    if not lo <= ratio <= hi:
        raise InputError(
            f"PAR / global radiation is {ratio:.3g} µmol J⁻¹ "
            f"(median over {int(bright.sum())} steps with global radiation > {RATIO_MIN_GHI_W_M2:g} W m⁻²)",
            file=file,
            column="par_umol_m2_s/ghi_w_m2",
            expected=f"{lo:g}–{hi:g} µmol J⁻¹ (sunlight ≈ 2.0–2.3): check PAR is in µmol m⁻² s⁻¹, "
            "global radiation in W m⁻², and that both share one clock",
        )
    return ratio


def clear_sky_ghi_w_m2(sun_elevation_deg: np.ndarray) -> np.ndarray:
    """Clear-sky global horizontal irradiance, W m⁻², of Haurwitz (1945; pvlib), which needs only the
    sun's elevation (degrees); 0 with the sun below the horizon. The bound both radiation checks
    judge a series against."""
    zenith = np.clip(90.0 - np.asarray(sun_elevation_deg, dtype=np.float64), 0.0, 180.0)
    return np.nan_to_num(np.asarray(pvlib.clearsky.haurwitz(pd.Series(zenith))["ghi"], dtype=np.float64))


def check_radiation_scale(
    df: pd.DataFrame, sun_elevation_deg: pd.Series, file=None, columns=("ghi_w_m2", "par_umol_m2_s")
) -> None:
    """Refuse radiation too small for its sun: ``columns`` of global radiation (W m⁻²) or PAR (µmol m⁻² s⁻¹,
    clear sky × 0.50 × 4.57 µmol J⁻¹) whose largest share of clear sky over the steps with the sun
    above :data:`CLEAR_SKY_MIN_ELEVATION_DEG` is below :data:`CLEAR_SKY_MIN_FRACTION` (a unit
    slip, e.g. kW m⁻² under a W m⁻² header). Series without such steps are not judged, nor series
    with daylight at two or more steps with the sun below the horizon: their timestamps are wrong, not
    their unit (:func:`check_light_fits_sun` says so). The error names the source column
    (``attrs["columns_used"]``) and the unit expected."""
    high = (sun_elevation_deg > CLEAR_SKY_MIN_ELEVATION_DEG).to_numpy()
    if not high.any():
        return
    night = (sun_elevation_deg < 0).to_numpy()
    el = np.asarray(sun_elevation_deg, dtype=np.float64)[high]
    clear_ghi = clear_sky_ghi_w_m2(el)
    used = df.attrs.get("columns_used", {})
    for col, clear, what, unit in (
        ("ghi_w_m2", clear_ghi, "global radiation", "W m⁻²"),
        ("par_umol_m2_s", par_from_ghi(clear_ghi), "PAR", "µmol m⁻² s⁻¹"),
    ):
        if col not in columns or col not in df.columns:
            continue
        margin = LIGHT_MARGIN_W_M2 * (1.0 if col == "ghi_w_m2" else PAR_PER_GHI_UMOL_J)
        if (np.asarray(df[col], dtype=np.float64)[night] > margin).sum() >= 2:
            continue
        v = np.asarray(df[col], dtype=np.float64)[high]
        if np.isnan(v).all():
            continue
        share = float(np.nanmax(v / clear))
        if share < CLEAR_SKY_MIN_FRACTION:
            raise InputError(
                f"{what} reaches at most {share:.2%} of clear sky (largest value {np.nanmax(v):.3g}) over the "
                f"{int(high.sum())} steps with the sun above {CLEAR_SKY_MIN_ELEVATION_DEG:g}°: the unit is wrong",
                file=file,
                column=used.get(col, col),
                expected=f"{what} in {unit} (≥ {CLEAR_SKY_MIN_FRACTION:.0%} of clear sky somewhere in daylight; "
                "a thick overcast gives 10–20 %)",
            )


#: A series with PAR only (global radiation estimated from it) whose PAR stays below this share of
#: clear-sky PAR at every step with the sun above :data:`CLEAR_SKY_MIN_ELEVATION_DEG`, and which × 4.57
#: would fit its sun, is cautioned: PAR in W m⁻² under the µmol column reads as ≈ 0.2 of clear sky on a
#: clear day (0.31 under broken-cloud enhancement), which the split turns into an overcast (20 April
#: 2016: noon diffuse share 0.99 against 0.27). Not refused: a thick overcast day in µmol m⁻² s⁻¹ stays
#: below it too (10–20 % of clear sky), so only a global radiation or diffuse column tells them apart.
PAR_ONLY_DIM_SHARE = 0.35


def par_only_caution(df: pd.DataFrame, sun_elevation_deg: pd.Series) -> dict | None:
    """The ``qc`` caution for a PAR-only series that may hold PAR in W m⁻² (:data:`PAR_ONLY_DIM_SHARE`),
    else ``None``."""
    el = np.asarray(sun_elevation_deg, dtype=np.float64)
    high = el > CLEAR_SKY_MIN_ELEVATION_DEG
    if not high.any():
        return None
    par = np.asarray(df["par_umol_m2_s"], dtype=np.float64)
    clear_par = par_from_ghi(clear_sky_ghi_w_m2(el))
    share = float(np.nanmax(par[high] / clear_par[high]))
    as_w = par * UMOL_PER_JOULE_PAR  # the series read as W m⁻² of PAR
    fits = (
        as_w > PAR_PER_GHI_UMOL_J * (LIGHT_MAX_CLEAR_SKY_FACTOR * clear_sky_ghi_w_m2(el) + LIGHT_MARGIN_W_M2)
    ).sum() < 2
    if share >= PAR_ONLY_DIM_SHARE or not fits:
        return None
    return {
        "kind": "caution",
        "column": "par_umol_m2_s",
        "count": int(high.sum()),
        "detail": f"PAR reaches at most {share:.0%} of clear-sky PAR over the {int(high.sum())} steps with the sun "
        f"above {CLEAR_SKY_MIN_ELEVATION_DEG:g}°, and the series has no global or diffuse radiation: the split "
        "reads it as overcast throughout. If the column holds PAR in W m⁻² (× "
        f"{UMOL_PER_JOULE_PAR:g} µmol J⁻¹ it would fit a clearer sky), convert it to µmol m⁻² s⁻¹; a "
        "ghi_w_m2 or diffuse_w_m2 column from the station would settle it",
    }


#: Light a sun can give at most: clear sky (Haurwitz) × this factor + :data:`LIGHT_MARGIN_W_M2`. Broken
#: clouds lift 10-minute global radiation to 1.3–1.4 × clear sky at most (cloud enhancement); the
#: margin covers twilight and sensor offsets near sunrise and sunset.
LIGHT_MAX_CLEAR_SKY_FACTOR = 1.5
LIGHT_MARGIN_W_M2 = 50.0
#: Darkness its sun cannot give: global radiation below DARK_MAX_W_M2 with the sun at least
#: DARK_SUN_MIN_DEG up. The darkest overcast still lets through ≈ 10 % of clear sky (≈ 4 W m⁻² at 5°).
DARK_SUN_MIN_DEG = 5.0
DARK_MAX_W_M2 = 1.0


def check_light_fits_sun(
    df: pd.DataFrame,
    sun_elevation_deg: pd.Series,
    file=None,
    columns=("ghi_w_m2", "par_umol_m2_s"),
    site: Site | None = None,
) -> None:
    """Refuse light that its sun cannot give: ``columns`` of global radiation (W m⁻²) or PAR
    (µmol m⁻² s⁻¹, as global radiation × 0.50 × 4.57 µmol J⁻¹) above clear sky ×
    :data:`LIGHT_MAX_CLEAR_SKY_FACTOR` + :data:`LIGHT_MARGIN_W_M2` at two or more steps: daylight with
    the sun below the horizon, noon light at a low sun; or below :data:`DARK_MAX_W_M2` at two or
    more steps with the sun :data:`DARK_SUN_MIN_DEG` or more up: night with the sun up (the CPlantBox
    April day placed on 23 June is dark at 06:50 with the sun 10° up). That is a wrong date (an
    undated file placed on a day its light does not fit), time zone or time label, which the Erbs
    split would turn into direct beams above the solar constant, or the wrong site (``site``, whose
    sun ``sun_elevation_deg`` is; named in the error). One step alone is left to the caller (a glitch)."""
    el = np.asarray(sun_elevation_deg, dtype=np.float64)
    clear = clear_sky_ghi_w_m2(el)
    bound = LIGHT_MAX_CLEAR_SKY_FACTOR * clear + LIGHT_MARGIN_W_M2
    at = "" if site is None else f" at {site.name}"
    if df.attrs.get("format") == "lightfit":  # UTC by definition: --tz is refused for it
        timing = "the file's UTC times (time_utc holds UTC, not local time)"
    else:
        timing = (
            "the file's time zone and time label (--weather-tz and --weather-time-label of a model command, "
            "--tz and --time-label of `lightfit weather show`)"
        )
    expected = (
        f"timestamps the light fits: the right date (--date places an undated file), {timing}, and the "
        f"site (--site, or --latitude, --longitude and --timezone; the sun was taken{at or ' at the site given'})"
    )
    used = df.attrs.get("columns_used", {})
    for col, scale, what, unit in (
        ("ghi_w_m2", 1.0, "global radiation", "W m⁻²"),
        ("par_umol_m2_s", PAR_PER_GHI_UMOL_J, "PAR", "µmol m⁻² s⁻¹"),
    ):
        if col not in columns or col not in df.columns:
            continue
        v = np.asarray(df[col], dtype=np.float64)

        def misfits(x, scale=scale):
            return np.flatnonzero(x > scale * bound), np.flatnonzero(
                (el >= DARK_SUN_MIN_DEG) & (x < scale * DARK_MAX_W_M2)
            )

        over, dark = misfits(v)
        for steps, worst, said in (  # the worst step named: the brightest against its bound, the highest sun
            (over, v[over] / (scale * bound[over]), "have more light than their sun can give"),
            (dark, el[dark], f"are darker than any sky with their sun {DARK_SUN_MIN_DEG:g}° or more up"),
        ):
            if len(steps) < 2:
                continue
            i = steps[np.argmax(worst)]
            # PAR in W m⁻² under a µmol header is 4.57× too dark: dawn reads as night with the sun up,
            # which the timestamps were blamed for. Said where the series × 4.57 fits its sun.
            slip = col == "par_umol_m2_s" and all(len(x) < 2 for x in misfits(v * UMOL_PER_JOULE_PAR))
            raise InputError(
                f"{what} {v[i]:.4g} {unit} at {df.index[i]:%Y-%m-%d %H:%M} UTC with the sun at {el[i]:.1f}°{at} (clear "
                f"sky {scale * clear[i]:.3g} {unit}): {len(steps)} steps {said}"
                + (f"; × {UMOL_PER_JOULE_PAR:g} µmol J⁻¹ every step would fit its sun: PAR in W m⁻²?" if slip else ""),
                file=file,
                column=used.get(col, col),
                expected=(f"PAR in {unit} (W m⁻² of PAR × {UMOL_PER_JOULE_PAR:g}), or " if slip else "") + expected,
            )


#: Derived columns a series may carry (a lightfit CSV written by ``lightfit weather show --csv``) and the
#: difference from their recomputed values that is reported rather than round-off (W m⁻², degrees).
_DERIVED_TOLERANCE = {"sun_elevation_deg": 0.01, "sun_azimuth_deg": 0.01, "dni_w_m2": 0.5, "dhi_w_m2": 0.5}


def _recomputed(before: pd.DataFrame, after: pd.DataFrame) -> list[dict]:
    """QC entries for derived columns that ``before`` carried and :func:`add_solar` replaced with
    different values (another site, split model or time label than the file was written with), so
    that no value of the file is replaced silently."""
    out = []
    for col, tol in _DERIVED_TOLERANCE.items():
        if col not in before.columns:
            continue
        diff = (after[col] - before[col].astype(float)).abs()
        differ = diff > tol
        if differ.any():
            unit = "°" if col.endswith("_deg") else " W m⁻²"
            out.append(
                {
                    "kind": "recomputed",
                    "column": col,
                    "count": int(differ.sum()),
                    "detail": f"the file's values replaced by those of this site and split model (up to "
                    f"{diff.max():.3g}{unit} apart); derived columns are always recomputed"
                    + (
                        " (a measured diffuse radiation belongs in a diffuse_w_m2 column, which then splits the light)"
                        if col == "dhi_w_m2" and "diffuse_w_m2" not in before.columns
                        else ""
                    ),
                }
            )
    return out


def _split_by_diffuse(out: pd.DataFrame, site: Site, qc: list[dict]) -> tuple[pd.DataFrame, str]:
    """The split ``"diffuse"`` of a series with its solar angles (:func:`add_solar`) and its quality
    note: by its diffuse PAR where it has one, else by its diffuse global radiation."""
    used, src = out.attrs.get("columns_used", {}), out.attrs.get("source")
    el = out["sun_elevation_deg"]
    if not any(c in out.columns for c in DIFFUSE_COLUMNS):
        raise InputError(
            "split 'diffuse' asked for a series without a diffuse radiation column",
            file=src,
            column=" or ".join(DIFFUSE_COLUMNS),
            expected="a diffuse_w_m2 (W m⁻²; in a TERENO export a RadiationDiffuse… column) or "
            "par_diffuse_umol_m2_s column, or the split erbs or boland",
        )
    if "par_diffuse_umol_m2_s" in out.columns:
        col = "par_diffuse_umol_m2_s"
        check_diffuse(
            out["par_umol_m2_s"],
            out[col],
            el,
            what="PAR",
            unit="µmol m⁻² s⁻¹",
            bright=float(par_from_ghi(RATIO_MIN_GHI_W_M2)),
            file=src,
            column=used.get(col, col),
        )
        par = out["par_umol_m2_s"].astype(float)
        kd_par = (out[col].astype(float) / par.where(par > 0)).clip(0.0, 1.0).fillna(1.0)
        diffuse = pd.Series(global_diffuse_fraction(kd_par, el), index=out.index) * out["ghi_w_m2"]
        split, cut = split_from_diffuse(out["ghi_w_m2"], diffuse, el, site, check=False)
        cut["diffuse_above_global"] = int(((el > 0) & (out[col] > par)).sum())
        detail = (
            "DNI and DHI from the series' diffuse PAR: PAR's diffuse fraction as measured, global radiation's "
            "by the inverse of Spitters et al. (1986)"
            + ("; diffuse_w_m2 not used" if "diffuse_w_m2" in out.columns else "")
        )
    else:
        split, cut = split_from_diffuse(
            out["ghi_w_m2"],
            out["diffuse_w_m2"],
            el,
            site,
            file=src,
            column=used.get("diffuse_w_m2"),
            ghi_estimated=any(q["kind"] == "derived" and q["column"] == "ghi_w_m2" for q in qc),
        )
        detail = "DNI and DHI from the series' diffuse radiation (GHI = DNI sin β + DHI)"
    if cut["diffuse_above_global"]:
        detail += f"; diffuse cut to its total at {cut['diffuse_above_global']} step(s)"
    if cut["beam_cut"]:
        detail += (
            f"; the beam cut near the horizon at {cut['beam_cut']} step(s) (none beyond 88° zenith, ≤ 1.1 × "
            "clear sky beyond 80°), the rest counted as diffuse"
        )
    return split, detail


def add_solar(df: pd.DataFrame, site: Site | None = None, split_model: str | None = None) -> pd.DataFrame:
    """Add the derived contract columns: sun angles, DNI/DHI and (if absent) PAR from GHI.

    ``split_model`` (:data:`SPLIT_MODELS`): ``None`` keeps the series' own (``attrs["split_model"]``,
    e.g. from a lightfit CSV written with one), else takes its diffuse radiation (``diffuse_w_m2``,
    :func:`split_from_diffuse`) where it has one, else Erbs. A decomposition model asked for by name
    is used even where a diffuse column exists (recorded in ``qc``).

    If only PAR was measured, global radiation is estimated as PAR / (0.50 × 4.57 µmol J⁻¹)
    so that the split can run; either estimate is recorded in ``attrs["qc"]``. With both measured,
    their ratio is checked (:func:`check_par_per_ghi`) and recorded there: the light model takes
    the PAR from the PAR sensor and its diffuse fraction from the split's (:func:`par_direct_diffuse`).
    Radiation in the series (global radiation, PAR) too small for its sun at the ``site`` is
    refused as a unit slip (:func:`check_radiation_scale`).

    The sun's angles are those at the centre of what each timestamp labels
    (:mod:`lightfit.weather.timestamps`): the stamp itself for instants, five minutes before it
    for the end-stamps of 10-minute means.
    """
    site = site or df.attrs.get("site") or SELHAUSEN
    out = df.copy()
    out.attrs = dict(df.attrs)
    qc = list(out.attrs.get("qc", []))
    k = PAR_PER_GHI_UMOL_J
    measured = [c for c in ("ghi_w_m2", "par_umol_m2_s") if c in out.columns]
    for c in measured:  # the split and PAR would turn a gap into no light at that step, silently
        gap = out[c].isna().to_numpy()
        if gap.any():
            raise InputError(
                f"{int(gap.sum())} missing value(s) (first at {out.index[np.flatnonzero(gap)[0]]})",
                file=out.attrs.get("source"),
                column=c,
                expected="a value at every step (lightfit's readers fill short gaps and refuse long ones)",
            )
    if {"par_umol_m2_s", "ghi_w_m2"} <= set(out.columns):
        ratio = check_par_per_ghi(out["par_umol_m2_s"], out["ghi_w_m2"], out.attrs.get("source"))
        # The check describes this series: a resampled one replaces its source's.
        qc = [q for q in qc if q["kind"] != "checked" or q["column"] != "par_umol_m2_s"]
        qc.append(
            {
                "kind": "checked",
                "column": "par_umol_m2_s",
                "count": len(out),
                "detail": f"PAR / global radiation {ratio:.3f} µmol J⁻¹ (median, global radiation > "
                f"{RATIO_MIN_GHI_W_M2:g} W m⁻²); the canopy is lit with the series' PAR",
            }
        )
    if "par_umol_m2_s" not in out.columns:
        out["par_umol_m2_s"] = par_from_ghi(out["ghi_w_m2"])
        qc.append(
            {
                "kind": "derived",
                "column": "par_umol_m2_s",
                "count": len(out),
                "detail": f"PAR estimated from global radiation × {k:.3f} µmol J⁻¹ "
                f"({PAR_FRACTION:.2f} × {UMOL_PER_JOULE_PAR:g})",
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
    stamps = timestamps.of(out)
    sp = solar_position(stamps.centres(out.index), site)
    out["sun_elevation_deg"] = sp["sun_elevation_deg"].to_numpy()
    out["sun_azimuth_deg"] = sp["sun_azimuth_deg"].to_numpy()
    check_radiation_scale(out, out["sun_elevation_deg"], out.attrs.get("source"), measured)
    check_light_fits_sun(out, out["sun_elevation_deg"], out.attrs.get("source"), measured, site or SELHAUSEN)
    qc = [q for q in qc if q["kind"] != "caution" or q["column"] != "par_umol_m2_s"]  # a resampled series' own
    # PAR only: global radiation estimated here, or by the add_solar of a series resampled since
    par_only = "ghi_w_m2" not in measured or any(q["kind"] == "derived" and q["column"] == "ghi_w_m2" for q in qc)
    if par_only and not any(c in out.columns for c in DIFFUSE_COLUMNS):
        caution = par_only_caution(out, out["sun_elevation_deg"])
        if caution is not None:
            qc.append(caution)
    if stamps.centre_offset != pd.Timedelta(0):
        qc = [q for q in qc if q["kind"] != "sun at centres"]  # a resampled series replaces its source's
        qc.append(
            {
                "kind": "sun at centres",
                "column": "sun_elevation_deg",
                "count": len(out),
                "detail": f"the timestamps are the {stamps.describe()}: the sun is taken at each interval's "
                f"centre ({stamps.centre_offset / pd.Timedelta(minutes=1):+g} min from its stamp)",
            }
        )
    has_diffuse = any(c in out.columns for c in DIFFUSE_COLUMNS)
    # Unasked, a series keeps the split it was given (a lightfit CSV's `split_model` line), else a
    # diffuse column decides.
    # Why this split, said in the checks; a resampled series keeps its source's reason (split_why).
    why = (
        "as asked"
        if split_model is not None
        else out.attrs.get("split_why") or ("its split_model line" if out.attrs.get("split_model") else "the default")
    )
    split_model = check_split_model(
        split_model or out.attrs.get("split_model") or ("diffuse" if has_diffuse else "erbs")
    )
    qc = [q for q in qc if q["kind"] != "split"]  # a resampled series replaces its source's
    if split_model == "diffuse":
        split, detail = _split_by_diffuse(out, site, qc)
        qc.append({"kind": "split", "column": None, "count": len(out), "detail": detail})
    else:
        split = split_direct_diffuse(
            out["ghi_w_m2"],
            out["sun_elevation_deg"],
            split_model,
            sp["sun_true_elevation_deg"].set_axis(out.index),
            stamps.interval,
        )
        if has_diffuse:
            qc.append(
                {
                    "kind": "split",
                    "column": None,
                    "count": len(out),
                    "detail": f"the series' diffuse radiation is not used: DNI and DHI split from global "
                    f"radiation by {split_model} ({why})",
                }
            )
        else:  # said as the diffuse column's split is (a review: a run on the CPlantBox day never named it)
            qc.append(
                {
                    "kind": "split",
                    "column": None,
                    "count": len(out),
                    "detail": f"DNI and DHI split from global radiation by {split_model} ({why}; the series has no "
                    "diffuse radiation)",
                }
            )
    out["dni_w_m2"], out["dhi_w_m2"] = split["dni_w_m2"], split["dhi_w_m2"]
    if any(c in df.columns for c in _DERIVED_TOLERANCE):  # a resampled series has none: keep its source's notes
        qc = [q for q in qc if q["kind"] != "recomputed"] + _recomputed(df, out)
    out.attrs["qc"] = qc
    out.attrs["site"] = site
    out.attrs["split_model"] = split_model
    out.attrs["split_why"] = why
    return out
