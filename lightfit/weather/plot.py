"""Forcing plot: radiation, temperature/humidity, CO2/pressure, sun elevation, one PNG."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import pandas as pd  # noqa: E402

from lightfit.figure import clock_axis, date_span, day_breaks, figure_format  # noqa: E402
from lightfit.weather.reconstruct import Anchor  # noqa: E402
from lightfit.weather.site import SELHAUSEN, zone_label  # noqa: E402
from lightfit.weather.units import PAR_PER_GHI_UMOL_J  # noqa: E402


def source_names(attrs: dict, key: str = "weather_source") -> str:
    """The file name(s) of the forcing in results ``attrs`` for a title: each once, ``"; "``-separated
    where several days' results list each day's (:func:`lightfit.replication.concat_days`)."""
    return "; ".join(dict.fromkeys(Path(s).name for s in str(attrs.get(key, "")).split("; ") if s))


def provenance_label(attrs: dict, key: str = "provenance", date_key: str = "date_given") -> str:
    """Upper-case provenance word for titles, so a reconstruction is never mistaken for data
    (``UNSTATED-PROVENANCE`` where neither the file nor the user said what it is); an undated
    file placed on a date by the caller says so (``MEASURED (undated file placed on 2016-04-27)``).
    ``attrs``: a series' (``provenance``, ``date_given``) or results' (``weather_provenance``,
    ``weather_date_given``)."""
    prov = str(attrs.get(key, "unstated"))
    word = "UNSTATED-PROVENANCE" if prov == "unstated" else prov.upper()
    return word + (f" (undated file placed on {attrs[date_key]})" if attrs.get(date_key) else "")


def plot_forcing(df: pd.DataFrame, path: str | Path, *, title: str | None = None, tz: str = SELHAUSEN.timezone) -> Path:
    """Write a four-panel figure of a contract series; the title states its provenance. The
    format comes from the suffix of ``path`` (:func:`lightfit.figure.figure_format`).

    Times are shown in ``tz`` (local civil time by default) and the axis says so.
    """
    path = Path(path)
    figure_format(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    local = df.tz_convert(tz)
    # a row of NaN in each night between several dates: a line through it would invent those hours
    drawn = local.reindex(local.index.append(day_breaks(local.index)).sort_values())
    t = drawn.index  # aware: drawn at their instants, so a clock change neither folds nor gaps the axis
    fig, ax = plt.subplots(4, 1, figsize=(9, 10), sharex=True, constrained_layout=True)
    # Estimated series say so under a MEASURED title: PAR from GHI or GHI from PAR, DNI and DHI from a split.
    derived = {q.get("column") for q in df.attrs.get("qc", []) if q.get("kind") == "derived"}
    estimated = ", estimated from GHI" if "par_umol_m2_s" in derived else ""
    ax[0].plot([], [], color="tab:orange", lw=2.5, label="PAR (µmol m⁻² s⁻¹)" + estimated)
    ax[0].set_ylabel("PAR\n(µmol m⁻² s⁻¹)")
    ax[0].plot(t, drawn["par_umol_m2_s"], color="tab:orange", lw=2.5)
    if {"dni_w_m2", "dhi_w_m2"} <= set(local.columns):
        r = ax[0].twinx()
        split = df.attrs.get("split_model")
        parts = "" if split == "diffuse" else f", estimated ({split or 'split'} split)"
        r.plot(
            t,
            drawn["ghi_w_m2"],
            color="k",
            lw=0.8,
            label="GHI" + (", estimated from PAR" if "ghi_w_m2" in derived else ""),
        )
        r.plot(t, drawn["dhi_w_m2"], color="tab:blue", lw=0.8, ls="--", label="DHI" + parts)
        r.plot(t, drawn["dni_w_m2"], color="tab:red", lw=0.8, ls=":", label="DNI" + parts)
        # One scale for both axes (PAR = 2.285 µmol J⁻¹ × GHI): the thin GHI line lies on the thick PAR
        # line where the two sensors agree and shows where they do not (free scales hid it exactly).
        k = PAR_PER_GHI_UMOL_J
        top = max(ax[0].get_ylim()[1], k * float(local[["ghi_w_m2", "dni_w_m2"]].max().max()) * 1.05)
        ax[0].set_ylim(0, top)
        r.set_ylim(0, top / k)
        r.set_ylabel(f"GHI, DHI, DNI\n(W m⁻²; × {k:.3f} = PAR scale)")
        r.legend(loc="upper right", fontsize=8)
    if a := Anchor.of(df.attrs):
        ta = a.time_utc.tz_convert(tz)
        ax[0].plot([ta], [a.par_umol_m2_s], "k*", ms=12, label="recorded chamber point (anchor)")
        ax[1].plot([ta], [a.tair_c], "k*", ms=12)
    ax[0].legend(loc="upper left", fontsize=8)
    ax[1].plot(t, drawn["tair_c"], color="tab:red")
    ax[1].set_ylabel("T air (°C)", color="tab:red")
    h = ax[1].twinx()
    h.plot(t, 100 * drawn["rh"], color="tab:blue")
    h.set_ylabel("RH (%)", color="tab:blue")

    def named(what: str, x: pd.Series, unit: str, fmt: str) -> str:
        # a constant series says so: two flat lines on twin axes meet and cannot be told apart
        return f"{what}, constant {x.iloc[0]:{fmt}} {unit}" if len(x) and (x == x.iloc[0]).all() else f"{what} ({unit})"

    co2 = ax[2].plot(t, drawn["co2_ppm"], color="tab:green", label=named("CO2", local["co2_ppm"], "ppm", ".0f"))
    ax[2].set_ylabel("CO2 (ppm)", color="tab:green")
    ax[2].ticklabel_format(axis="y", useOffset=False)  # ppm as read: an offset made 0.01 ppm look like a signal
    lo, hi = ax[2].get_ylim()
    if hi - lo < 10:  # so did a span of 0.01 ppm (unit conversion's rounding); a crop's diurnal course is tens of ppm
        ax[2].set_ylim((lo + hi) / 2 - 5, (lo + hi) / 2 + 5)
    p = ax[2].twinx()
    pair = named("air pressure", local["pair_kpa"], "kPa", ".1f")
    kpa = p.plot(t, drawn["pair_kpa"], color="tab:gray", ls="--", lw=1.0, label=pair)
    p.set_ylabel("p (kPa)", color="tab:gray")
    ax[2].legend(handles=co2 + kpa, loc="upper left", fontsize=8)
    if "sun_elevation_deg" in local.columns:
        ax[3].plot(t, drawn["sun_elevation_deg"], color="goldenrod")
        ax[3].axhline(0, color="k", lw=0.5)
    ax[3].set_ylabel("sun elevation (°)")
    # the date(s) in local time, as the replication figure's axis says them: the clock alone names no day
    day = date_span(local.index)
    ax[3].set_xlabel(f"local time ({zone_label(tz)})" + (f", {day}" if day else ""))
    clock_axis(ax[3], tz)
    src = Path(str(df.attrs.get("source", ""))).name
    fig.suptitle(title or f"{provenance_label(df.attrs)} forcing — {src}", fontsize=11)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
