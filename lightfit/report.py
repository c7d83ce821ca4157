"""What a replication run reports: the summary table and the Fig-4-like figure (units:
:mod:`lightfit.model.schema`)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from lightfit.plant import Field


def summary(ds) -> pd.DataFrame:
    """One row per time step: sun, above-canopy PAR (the weather's), plant PAR (mean, spread),
    canopy An and its Monte Carlo SD, share of light-limited blades (units: :mod:`lightfit.model.schema`)."""
    t = pd.DatetimeIndex(ds["time"].values).tz_localize("UTC")
    blades = ds["is_blade"].values.astype(bool)
    lim = ds["limitation"].values[:, blades]
    light_limited = np.where((lim >= 0).any(1), (lim == 1).sum(1) / np.maximum((lim >= 0).sum(1), 1), np.nan)
    return pd.DataFrame(
        {
            "local_time": t.tz_convert("Europe/Berlin").strftime("%H:%M"),
            "sun_elevation_deg": ds["sun_elevation_deg"].values,
            **{
                k: ds[k].values
                for k in (
                    "above_canopy_par_umol_m2_s",
                    "plant_par_umol_m2_s",
                    "plant_par_spread_umol_m2_s",
                    "canopy_an_umol_m2_s",
                    "canopy_an_mc_sd_umol_m2_s",
                )
            },
            "frac_light_limited": light_limited,
        },
        index=t.rename("time_utc"),
    )


def field_label(attrs) -> str:
    """The field's boundary in words, from results attrs (or a :class:`~lightfit.plant.Field`)."""
    if isinstance(attrs, Field):
        attrs = {"boundary": attrs.boundary, "buffer_rows": attrs.buffer_rows, "buffer_along": attrs.b_along}
    if attrs.get("boundary", "finite") == "periodic":
        return "periodic boundary (one cell of an infinite field)"
    rows, along = attrs.get("buffer_rows"), attrs.get("buffer_along", attrs.get("buffer_rows"))
    return f"finite field, {rows} buffer rows" + ("" if along == rows else f" and {along} plants along")


def plot(ds, path: Path) -> Path:
    """Fig-4-like: plant PAR (mean ± spread across segments) and canopy net CO2 uptake over the day."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.dates as mdates
    import matplotlib.pyplot as plt

    t = pd.DatetimeIndex(ds["time"].values).tz_localize("UTC").tz_convert("Europe/Berlin").tz_localize(None)
    fig, ax = plt.subplots(figsize=(10, 5.5), constrained_layout=True)
    par, sd = ds["plant_par_umol_m2_s"].values, ds["plant_par_spread_umol_m2_s"].values
    kind = ds.attrs.get("par_kind", "absorbed")
    ax.fill_between(t, np.maximum(par - sd, 0), par + sd, color="tab:blue", alpha=0.2, label="± SD across segments")
    ax.plot(t, par, color="tab:blue", lw=2, label=f"model: {kind} PAR at the plants, mean over segments")
    if "above_canopy_par_umol_m2_s" in ds:
        # What a horizontal quantum sensor above the canopy reads: the quantity the chamber's PAR
        # record is, so the observation is compared with it rather than with PAR at the plants.
        ax.plot(
            t,
            ds["above_canopy_par_umol_m2_s"].values,
            color="grey",
            lw=1.5,
            ls="--",
            label="forcing: PAR above the canopy (horizontal)",
        )
    if "obs_plant_par_umol_m2_s" in ds:
        ax.errorbar(
            t,
            ds["obs_plant_par_umol_m2_s"].values,
            yerr=ds["obs_plant_par_sd_umol_m2_s"].values,
            fmt="s",
            color="navy",
            label="observed PAR (chamber quantum sensor, above the canopy)",
        )
    ax.set_ylabel("PAR (µmol m⁻² s⁻¹)", color="tab:blue")
    ax2 = ax.twinx()
    an, an_sd = ds["canopy_an_umol_m2_s"].values, ds["canopy_an_mc_sd_umol_m2_s"].values
    per = ds.attrs.get("an_per", "ground")
    ax2.fill_between(t, an - 2 * an_sd, an + 2 * an_sd, color="tab:red", alpha=0.2)
    ax2.plot(t, an, color="tab:red", lw=2, label=f"model: net CO2 uptake per {per} area (±2 MC SD)")
    if "obs_canopy_an_umol_m2_s" in ds and np.isfinite(ds["obs_canopy_an_umol_m2_s"].values).any():
        ax2.errorbar(
            t,
            ds["obs_canopy_an_umol_m2_s"].values,
            yerr=ds["obs_canopy_an_sd_umol_m2_s"].values,
            fmt="o",
            color="darkred",
            label="observed net CO2 uptake",
        )
    ax2.set_ylabel(f"net CO2 uptake (µmol m⁻² {per} s⁻¹)", color="tab:red")
    ax.xaxis.set_major_formatter(mdates.DateFormatter("%H:%M"))
    ax.set_xlabel("local time (Europe/Berlin), 2016-04-20")
    h1, l1 = ax.get_legend_handles_labels()
    h2, l2 = ax2.get_legend_handles_labels()
    ax.legend(h1 + h2, l1 + l2, loc="upper left", fontsize=8)
    prov = ds.attrs.get("weather_provenance", "unknown").upper()
    fig.suptitle(
        f"Selhausen 2016-04-20 replication — {prov} forcing\n{ds.attrs.get('n_plants')} plants, "
        f"{field_label(ds.attrs)}, K={ds.attrs.get('samples')}, photosynthesis {ds.attrs.get('photosynthesis')}",
        fontsize=11,
    )
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
