"""The 20 April 2016 Selhausen replication: the main job.

CPlantBox wheat grown from 2016-03-05 to 2016-04-20, a 10 × 10-plant measurement area as one
cell of an infinite periodic field (default; ``boundary="finite"`` with two buffer rows is the
reference paper's setup), the day's forcing (bundled reconstruction unless a real TERENO export is given),
05:00–19:00 local time in 30-minute steps (29 steps), light and photosynthesis per segment.
Outputs: results netCDF (time × segment), a Fig-4-like PNG (PAR with its spread across
segments, canopy net CO2 uptake, observations where present), the forcing, and a summary table.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
import pandas as pd

from lightfit import weather
from lightfit.inference.observations import align, read_observations
from lightfit.model import schema
from lightfit.model.coupled import CoupledModel
from lightfit.model.parameters import Theta
from lightfit.model.scenario import Scenario
from lightfit.plant import Field
from lightfit.weather.bundled import DATA_DIR

START_LOCAL = "2016-04-20 05:00"
HOURS, STEP = 14.0, "30min"
OBSERVATIONS = DATA_DIR / "observations" / "chamber_2016-04-20_record.csv"


@dataclass(frozen=True)
class ReplicationConfig:
    """Knobs of the replication; ``quick()`` is the under-a-minute first look (and the CI size).

    ``boundary``: ``"periodic"`` (default: the measurement area is one cell of an infinite field,
    no buffer plants; docs/light.md, "Periodic boundary") or ``"finite"`` (buffer rows on bare
    soil; with ``buffer_rows=None`` → 2, the reference paper's setup). ``buffer_rows`` /
    ``buffer_along``: ``None`` means the boundary's default (2 finite, 0 periodic); explicit
    non-zero buffers with a periodic boundary are refused (:class:`lightfit.plant.Field`).
    """

    n_plants: int = 100
    boundary: str = "periodic"
    buffer_rows: int | None = None
    buffer_along: int | None = None
    seed: int = 1
    samples: int = 64
    bounces: int = 3
    render_seed: int = 0
    par_kind: str = "absorbed"
    an_per: str = "ground"
    how: str = "sample"
    photosynthesis: str = Scenario.photosynthesis

    @staticmethod
    def quick() -> ReplicationConfig:
        return ReplicationConfig(n_plants=4, samples=16, bounces=2)

    def finite(self, buffer_rows: int = 2, buffer_along: int | None = None) -> ReplicationConfig:
        """The same run on a finite field; the defaults are the reference paper's 2 buffer rows."""
        return replace(self, boundary="finite", buffer_rows=buffer_rows, buffer_along=buffer_along)

    def field(self) -> Field:
        """The run's :class:`~lightfit.plant.Field` (checks boundary and buffers)."""
        return Field(
            n_plants=self.n_plants,
            buffer_rows=self.buffer_rows,
            seed=self.seed,
            buffer_along=self.buffer_along,
            boundary=self.boundary,
        )


def forcing(weather_file: str | Path | None = None, how: str = "sample") -> pd.DataFrame:
    """The run's 29 steps: bundled reconstruction, or the given weather file, with solar columns."""
    src = (
        weather.read_weather(weather_file) if weather_file else weather.read_weather(weather.bundled_path("2016-04-20"))
    )
    src = weather.add_solar(src)
    return weather.window(src, START_LOCAL, HOURS, STEP, how=how)


def scenario_for(cfg: ReplicationConfig, w: pd.DataFrame) -> Scenario:
    """The :class:`Scenario` of a configuration over the forcing ``w`` (the one place that maps one to the other)."""
    return Scenario(
        weather=w,
        field=cfg.field(),
        samples=cfg.samples,
        bounces=cfg.bounces,
        seed=cfg.render_seed,
        par_kind=cfg.par_kind,
        an_per=cfg.an_per,
        photosynthesis=cfg.photosynthesis,
    )


def model_for(cfg: ReplicationConfig, w: pd.DataFrame, progress: bool = False) -> CoupledModel:
    return CoupledModel(scenario_for(cfg, w), progress=progress)


def run(
    cfg: ReplicationConfig,
    *,
    weather_file=None,
    theta: Theta | dict | None = None,
    observations=OBSERVATIONS,
    out: Path | None = None,
    progress: bool = False,
    forcing_df: pd.DataFrame | None = None,
):
    """Run the replication; write outputs to ``out`` if given. Returns (Dataset, observations or None).

    ``forcing_df``: the run's forcing if already read (``forcing(weather_file, cfg.how)``).
    """
    w = forcing(weather_file, cfg.how) if forcing_df is None else forcing_df
    model = model_for(cfg, w, progress)
    ds = model.simulate(theta)
    ds.attrs["replication_config"] = json.dumps(asdict(cfg))
    obs = read_observations(observations) if observations else None
    if obs is not None:
        a = align(obs, model.times)
        for k, v in a.items():
            ds[f"obs_{k}"] = ("time", v)
        schema.annotate(ds)
        ds.attrs["observations"] = f"{obs.attrs['source']} ({obs.attrs['provenance']})"
    if out is not None:
        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        write_netcdf(ds, out / "results.nc")
        plot(ds, out / "replication.png")
        summary(ds).to_csv(out / "summary.csv", float_format="%.4g")
    return ds, obs


def write_netcdf(ds, path: Path) -> Path:
    """netCDF4 via h5netcdf (booleans stored as int8)."""
    ds = ds.copy()
    for v in list(ds.variables):
        if ds[v].dtype == bool:
            ds[v] = ds[v].astype(np.int8)
    ds.to_netcdf(path, engine="h5netcdf")
    return path


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
