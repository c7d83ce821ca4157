"""What a replication run reports: the summary table and the Fig-4-like figure (units:
:mod:`lightfit.model.schema`)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd

from lightfit.defaults import MAX_ADAPTIVE_SAMPLES
from lightfit.figure import clock_axis, date_span, gapped
from lightfit.photosynthesis.canopy import PROFILES
from lightfit.photosynthesis.parameters import ACCLIMATING_SETS
from lightfit.plant import Field
from lightfit.weather.site import local_clock, zone_label

#: Per-time variables of the summary table (those a results file has), after local time and sun.
SUMMARY_COLUMNS = (
    "above_canopy_par_umol_m2_s",
    "plant_par_umol_m2_s",
    "plant_par_spread_umol_m2_s",
    "canopy_apar_umol_m2_s",
    "fapar",
    "canopy_an_umol_m2_s",
    "canopy_an_mc_sd_umol_m2_s",
)


def summary(ds) -> pd.DataFrame:
    """One row per time step: sun, the model's above-canopy PAR sensor, plant PAR (mean, spread),
    canopy APAR and fAPAR, canopy An and its Monte Carlo SD, share of light-limited blades and the
    number of blades whose photosynthesis solve did not converge (units: :mod:`lightfit.model.schema`)."""
    from lightfit.model.coupled import unconverged_per_step

    t = pd.DatetimeIndex(ds["time"].values).tz_localize("UTC")
    blades = ds["is_blade"].values.astype(bool)
    lim = ds["limitation"].values[:, blades]
    light_limited = np.where((lim >= 0).any(1), (lim == 1).sum(1) / np.maximum((lim >= 0).sum(1), 1), np.nan)
    return pd.DataFrame(
        {
            "local_time": local_clock(t, site_timezone(ds)),
            "sun_elevation_deg": ds["sun_elevation_deg"].values,
            **{k: ds[k].values for k in SUMMARY_COLUMNS if k in ds},
            "frac_light_limited": light_limited,
            "unconverged_blades": unconverged_per_step(ds),
        },
        index=t.rename("time_utc"),
    )


def _plants(attrs):
    """The plants a results file's field measures: its ``n_plants`` attribute is the field's setting,
    which the field rounds up to a square (5 builds 3 × 3) or to whole rows (``plants_per_row``). An
    attribute that is no plant count (a file written elsewhere) is shown as it stands: a header or
    title is no place to refuse it."""
    n = attrs.get("n_plants")
    try:
        return Field(n_plants=n, plants_per_row=attrs.get("plants_per_row")).n_measured
    except (TypeError, ValueError):  # InputError is a ValueError
        return n


def samples_label(samples: int, target_rse: float | None, max_samples: int | None = None) -> str:
    """What a run says about its samples: ``K=32``, or an adaptive run's target and the range of K
    per segment (its pilot and the cap ``max_samples``, default
    :data:`~lightfit.defaults.MAX_ADAPTIVE_SAMPLES`, as ``make_irradiance`` takes them)."""
    from lightfit.light.estimator import adaptive_pilot

    if target_rse is None:
        return f"K={samples}"
    pilot = adaptive_pilot(samples)
    cap = MAX_ADAPTIVE_SAMPLES if max_samples is None else int(max_samples)
    return f"target {target_rse:.3g} (K from {pilot} to {max(cap, pilot)} per segment)"


def summary_metadata(ds) -> dict[str, str]:
    """The ``# key: value`` header of a results folder's summary.csv: that it is model output, the
    forcing's and the observations' provenance and files, the preset and any θ given, site, window
    (and the steps run, where not all of it) and field, where fAPAR exceeds 1 how often and why (a
    finite field's sides: :func:`fapar_over_one`), and lightfit's versions; every setting is in
    results.nc's attributes. Without it the table could pass for numbers from measured weather (data
    honesty: a reconstructed forcing says so here)."""
    a = ds.attrs
    field = f"{_plants(a)} plants, {a.get('boundary')} boundary"
    # an adaptive run's K is per segment: its target said, not the pilot's base K (a review)
    k = samples_label(a.get("samples"), a.get("target_rse"), a.get("max_samples"))
    field += f", {k}, {a.get('bounces')} bounces"
    meta = {
        "content": "lightfit model output, one row per time step (units in the column names)",
        "forcing_provenance": a.get("weather_provenance", "unstated"),
        "forcing_source": a.get("weather_source"),
        "observations": a.get("observations"),
        "observations_fit": None if (fit := observations_fit(ds)) is None else fit_text(fit),
        "preset": a.get("preset"),
        "theta_given": a.get("theta_given"),  # --theta: the leaf and scales are not the preset's
        "site": a.get("site"),
        "window": a.get("window"),
        "steps_run": a.get("steps_run"),  # --steps: only these steps of the window ran
        "local_time": f"the site's clock, HH:MM in {site_timezone(ds)} (time_utc is UTC)",
        "field": field,
        "fapar": fapar_over_one(ds),
        "software_versions": a.get("software_versions"),
        "settings": "every setting is an attribute of results.nc beside this file",
    }
    return {k: v for k, v in meta.items() if v is not None}


def fapar_over_one(ds) -> str | None:
    """Where fAPAR exceeds 1 (a finite field's measured plants lit through its sides): how often, how
    far, per which ground area and why, for summary.csv's header and the command's note
    (:func:`lightfit.cli.replicate.edge_line`); ``None`` where it stays at or below 1."""
    if "fapar" not in ds:
        return None
    fapar = np.asarray(ds["fapar"].values, dtype=float)
    over = fapar > 1.0
    if not over.any():
        return None
    area = ds.attrs.get("ground_area_m2")
    per = "per ground area of the measured plants" + (f" ({float(area):.4g} m2)" if area is not None else "")
    return (
        f"above 1 at {int(over.sum())} of {fapar.size} steps (up to {np.nanmax(fapar):.2f}): APAR is {per}, "
        f"which take light through the sides of the {ds.attrs.get('boundary', 'finite')} field, so APAR, "
        "PAR at the plants and An are an edge's, not a canopy's (docs/model.md; the periodic default has no edge)"
    )


def fit_attribute(fit: pd.DataFrame) -> str:
    """The results attribute ``observations_fit`` of a table of
    :meth:`~lightfit.inference.likelihood.GaussianLikelihood.series_fit` (:func:`observations_fit`
    reads it back): JSON by series, every float to the last digit, an unconverged run's χ² as
    ``Infinity`` (pandas' ``to_json`` writes it as null, read back as NaN)."""
    return json.dumps(fit.to_dict(orient="index"))


def observations_fit(ds) -> pd.DataFrame | None:
    """How a run's model met its observations, one row per series (index: the series' name): ``n``
    steps with a reading, ``bias`` (mean of model − observed) and ``rmse`` in the series' ``unit``, and ``chi2``
    of the series alone with the observations' SDs and the model's Monte Carlo SDs (the results'
    ``observations_fit`` attribute, written by :func:`lightfit.replication.run` with
    :meth:`~lightfit.inference.likelihood.GaussianLikelihood.series_fit`); ``None`` for a run
    without observations. ``ds``: the results (an xarray Dataset) or the path of a results.nc."""
    if isinstance(ds, str | Path):
        import xarray as xr

        from lightfit.errors import InputError
        from lightfit.files import is_netcdf

        path = Path(ds)
        if not path.is_file() or not is_netcdf(path):
            raise InputError("not a netCDF file", file=path, expected="a results.nc written by the coupled model")
        with xr.open_dataset(path, engine="h5netcdf") as opened:
            ds = xr.Dataset(attrs=dict(opened.attrs))
    text = ds.attrs.get("observations_fit")
    if not text:
        return None
    fit = pd.DataFrame.from_dict(json.loads(text), orient="index").rename_axis("series")
    return fit.astype({"n": int, "bias": float, "rmse": float, "chi2": float})


def fit_text(fit: pd.DataFrame) -> str:
    """One line per series of :func:`observations_fit`, joined by "; ": ``above_canopy_par: n 3,
    bias +12.1, RMSE 15 umol m-2 s-1, χ² 4.2``."""
    return "; ".join(
        f"{name}: n {r.n}, bias {r.bias:+.3g}, RMSE {r.rmse:.3g} {r.unit}, χ² {r.chi2:.3g}"
        for name, r in fit.iterrows()
    )


def site_timezone(ds) -> str:
    """The run's local time zone (results attr ``site_timezone``; Selhausen's before sites were options)."""
    from lightfit.weather.site import Site

    return Site.from_attrs(ds.attrs).timezone


def preset_name(attrs, other: str = "this run") -> str:
    """``"default"`` or ``"paper"`` when the run's model choices are those of a named preset
    (``attrs["preset"]``, :attr:`lightfit.replication.ReplicationConfig.preset`), else ``other``."""
    name = attrs.get("preset", "none")
    return other if name in ("none", None, "") else str(name)


def run_label(attrs) -> str:
    """The model choices of a run in words (leaf optics, sheaths, photosynthesis set, field), from results attrs."""
    cfg = json.loads(attrs.get("replication_config", "{}") or "{}")
    optics = cfg.get("optics") or f"base colour {float(attrs.get('base_color', np.nan)):.3g}"
    sheaths = attrs.get("sheaths", "rods")  # results written before the setting had CPlantBox's rods
    profile = attrs.get("vcmax_profile", "uniform")  # results written before profiles: every blade alike
    notes = [] if profile == "uniform" else [f"{profile} profile" if profile in PROFILES else f"kn {profile}"]
    t_g, own = attrs.get("growth_temperature_c"), ACCLIMATING_SETS.get(attrs.get("photosynthesis"))
    if t_g is not None and own is not None:
        text, applied = (
            v if isinstance(v, str) else f"{float(v):.3g}"
            for v in (t_g, attrs.get("growth_temperature_applied_c", t_g))
        )  # several days: "9.3; 13.1"
        if text != f"{own:.3g}":
            notes.append(f"T_g {text} °C" + ("" if applied == text else f", acting as {applied} °C"))
    # results written before overrides have none
    notes += [f"{k} {v:g}" for k, v in json.loads(attrs.get("photosynthesis_overrides", "{}")).items()]
    ps = f"photosynthesis {attrs.get('photosynthesis')}" + (f" ({', '.join(notes)})" if notes else "")
    # results written before the setting had CPlantBox's plants, all facing the same way
    aligned = ", aligned plants" if attrs.get("headings", "aligned") == "aligned" else ""
    return f"leaf {optics}, {sheaths} sheaths{aligned}, {ps}, {field_label(attrs)}"


def field_label(attrs) -> str:
    """The field's boundary in words, from results attrs (or a :class:`~lightfit.plant.Field`)."""
    if isinstance(attrs, Field):
        attrs = {"boundary": attrs.boundary, "buffer_rows": attrs.buffer_rows, "buffer_along": attrs.b_along}
    if attrs.get("boundary", "finite") == "periodic":
        return "periodic boundary (one cell of an infinite field)"
    rows, along = attrs.get("buffer_rows"), attrs.get("buffer_along", attrs.get("buffer_rows"))
    label = f"finite field, {rows} buffer row{'' if rows == 1 else 's'}"
    return label + ("" if along == rows else f" and {along} plant{'' if along == 1 else 's'} along")


def step_instants(ds) -> pd.DatetimeIndex:
    """Each step at the instant it stands for (UTC), where the figure draws it: a mean's interval
    centre (``time_bnds``, as the sun was taken), otherwise its stamp."""
    b = ds["time_bnds"].values if "time_bnds" in ds else None
    t = ds["time"].values if b is None else b[:, 0] + (b[:, 1] - b[:, 0]) / 2
    return pd.DatetimeIndex(t).tz_localize("UTC")


def plot(ds, path: Path, compare=None) -> Path:
    """:func:`figure` written to ``path`` (the format from its suffix)."""
    import matplotlib.pyplot as plt

    fig = figure(ds, compare)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def figure(ds, compare=None):
    """The replication figure: like with like, one panel per kind of quantity.

    (a) PAR per ground area — on a horizontal quantum sensor above the canopy, the model's sensor
    (``above_canopy_par_umol_m2_s``) with the observed above-canopy PAR (the chamber's record) and
    the weather series' own PAR, and what the canopy absorbs of it (canopy APAR), with any
    observations of these; (b) PAR absorbed (or incident) at the plants per one-sided leaf/stem
    area, the area-weighted mean over segments with the band of the segments' 10–90 % of area, with
    any observations of it (per-ground and per-leaf-area fluxes never share an axis); (c) canopy net
    CO2 uptake per ground (or leaf) area ± 2 Monte Carlo SD, with observed uptake. ``compare``: a
    second run's results (e.g. the ``paper`` preset,
    :meth:`lightfit.replication.ReplicationConfig.paper`) drawn dashed beside this one's.
    Observations are labelled with their provenance (legends and title), as the forcing is.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    tz = site_timezone(ds)

    def local(d):  # aware: drawn at their instants, so a clock change neither folds nor gaps the axis
        return step_instants(d).tz_convert(tz)

    t = local(ds)
    fig, (ax_a, ax_b, ax_c) = plt.subplots(3, 1, figsize=(10, 11), sharex=True, constrained_layout=True)

    def name(d, other="this run"):  # a given θ is not the preset's leaf: the legends say so too
        return preset_name(d.attrs, other) + (", θ given" if d.attrs.get("theta_given") else "")

    runs = [(ds, "-", f"{name(ds)}: {run_label(ds.attrs)}")]
    if compare is not None:
        runs.append((compare, "--", f"{name(compare, 'compared')}: {run_label(compare.attrs)}"))
    # the bands of (b) and (c) are the main run's alone: with a compared run drawn, their labels say so
    whose = "" if compare is None else f" — solid line ({runs[0][2].split(':')[0]}) only"

    # (a) per ground area: above the canopy, and what the canopy absorbs of it
    for d, ls, lab in runs:
        who = lab.split(":")[0]
        sensor = f"model sensor ({who}, light factor {d.attrs.get('theta_light_factor', 1):.3g})"
        for var, color, lw, label in (
            ("above_canopy_par_umol_m2_s", "darkorange", 2, sensor),
            ("canopy_apar_umol_m2_s", "tab:green", 1.5, f"absorbed by the canopy, APAR ({who})"),
        ):
            if var in d:
                ax_a.plot(*gapped(local(d), d[var].values), color=color, lw=lw, ls=ls, label=label)
    if "weather_par_umol_m2_s" in ds:  # drawn over the model's sensor, which it equals at light factor 1
        ax_a.plot(
            *gapped(t, ds["weather_par_umol_m2_s"].values),
            color="k",
            lw=1,
            ls=":",
            label="weather series' PAR",
            zorder=3,
        )
    _observed(ax_a, ds, t, "above_canopy_par", "s", "navy", "PAR above the canopy")
    _observed(ax_a, ds, t, "canopy_apar", "D", "darkgreen", "canopy APAR")
    ax_a.set_ylabel("PAR per ground area\n(µmol m⁻² ground s⁻¹)")
    ax_a.set_title(
        "(a) PAR per ground area: above the canopy (horizontal quantum sensor) and absorbed by it",
        loc="left",
        fontsize=10,
    )

    # (b) at the plants
    kind = ds.attrs.get("par_kind", "absorbed")
    for i, (d, ls, lab) in enumerate(runs):
        par, sd = d["plant_par_umol_m2_s"].values, d["plant_par_spread_umol_m2_s"].values
        k = d.attrs.get("par_kind", kind)
        if i == 0 and f"{k}_par_umol_m2_s" in d and "area_m2" in d.coords:
            # the segments' range, area-weighted: PAR ≥ 0 is skewed, and mean ± SD was cut at 0
            lo, hi = area_quantiles(d[f"{k}_par_umol_m2_s"].values, d["area_m2"].values, (0.1, 0.9))
            ax_b.fill_between(
                *gapped(t, lo, hi), color="tab:blue", alpha=0.2, label=f"10–90 % of the segments' area{whose}"
            )
        elif i == 0:
            ax_b.fill_between(
                *gapped(t, np.maximum(par - sd, 0), par + sd),
                color="tab:blue",
                alpha=0.2,
                label=f"± SD of segments, cut at 0{whose}",
            )
        ax_b.plot(
            *gapped(local(d), par),
            color="tab:blue",
            lw=2,
            ls=ls,
            label=f"{k} PAR per leaf/stem area, mean over segments ({lab.split(':')[0]})",
        )
    _observed(ax_b, ds, t, "plant_par", "s", "navy", "PAR at the plants")
    ax_b.set_ylabel("PAR at the plants\n(µmol m⁻² leaf/stem s⁻¹)")
    ax_b.set_title("(b) PAR at the plants per one-sided leaf/stem area", loc="left", fontsize=10)

    # (c) net CO2 uptake
    per = ds.attrs.get("an_per", "ground")
    for i, (d, ls, lab) in enumerate(runs):
        an, an_sd = d["canopy_an_umol_m2_s"].values, d["canopy_an_mc_sd_umol_m2_s"].values
        if i == 0:  # its width in the label: often narrower than the line
            width = f" (at most ± {2 * np.nanmax(an_sd):.2g})" if np.isfinite(an_sd).any() else ""
            ax_c.fill_between(
                *gapped(t, an - 2 * an_sd, an + 2 * an_sd),
                color="tab:red",
                alpha=0.2,
                label=f"± 2 Monte Carlo SD{width}{whose}",
            )
        ax_c.plot(*gapped(local(d), an), color="tab:red", lw=2, ls=ls, label=f"model ({lab.split(':')[0]})")
    _observed(ax_c, ds, t, "canopy_an", "o", "darkred", "net CO2 uptake")
    ax_c.axhline(0, color="k", lw=0.5)
    ax_c.set_ylabel(f"canopy net CO2 uptake\n(µmol m⁻² {per} s⁻¹)")
    ax_c.set_title(
        f"(c) canopy net CO2 uptake per {per} area (leaf dark respiration included)", loc="left", fontsize=10
    )

    day = date_span(t)  # several dates (--date twice): the axis spans them all
    clock_axis(ax_c, tz)
    ax_c.set_xlabel(f"local time ({zone_label(tz)}), {day}")
    for ax in (ax_a, ax_b, ax_c):
        ax.grid(alpha=0.3)
        ax.legend(loc="center left", bbox_to_anchor=(1.01, 0.5), fontsize=8, frameon=False)
    from lightfit.weather.plot import provenance_label, source_names

    prov = provenance_label(ds.attrs, "weather_provenance", "weather_date_given")
    # several days' results list each day's file where they differ (concat_days)
    src = source_names(ds.attrs)
    lines = [
        f"{ds.attrs.get('site', 'Selhausen')} {ds.attrs.get('date', day)} — {prov} forcing ({src}); "
        f"{run_size(ds.attrs)}",
        runs[0][2],
    ]
    if "observations" in ds.attrs:  # a line of its own: the title must fit the figure's width
        source, word = _observations_source(ds)
        lines.insert(1, f"{word.upper()} observations ({Path(source).name})")
    if ds.attrs.get("theta_given"):  # the leaf and scales given (--theta), not the preset's defaults
        given = json.loads(ds.attrs["theta_given"])
        lines.append("θ given: " + ", ".join(f"{k} {float(v):.4g}" for k, v in given.items()))
    if compare is not None:  # its own size: a preset resolves K and bounces for its leaf and light
        lines.append(runs[1][2] + f" (dashed; {run_size(compare.attrs)})")
    # wrapped at the figure's edges: a run label with a given θ, a profile and overrides is wider than it
    fig.suptitle("\n".join(lines), fontsize=10, wrap=True)
    return fig


def run_size(attrs) -> str:
    """A run's size in the figure's title, from results attrs: its measured plants, K (an adaptive
    run's target and K range per segment, not the pilot's base K) and scattering orders
    (``4 plants, K=16, 2 bounces``)."""
    k = samples_label(attrs.get("samples"), attrs.get("target_rse"), attrs.get("max_samples"))
    n_b = attrs.get("bounces")  # a file without the attribute: unsaid, not "None bounces"
    return f"{_plants(attrs)} plants, {k}" + ("" if n_b is None else f", {n_b} bounces")


def area_quantiles(values: np.ndarray, area_m2: np.ndarray, qs) -> np.ndarray:
    """Area-weighted quantiles ``qs`` (fractions) of ``values`` (T, S) over the segments of one-sided
    areas ``area_m2`` (S,), per row: (len(qs), T), in the values' unit. The q-quantile is the
    smallest value below which (inclusive) at least q of the area lies. NaN values (a segment of
    another day in several days' results) weigh nothing; a row without any value is NaN."""
    values, area = np.atleast_2d(np.asarray(values, float)), np.asarray(area_m2, float)
    out = np.full((len(qs), values.shape[0]), np.nan)
    if values.shape[1] == 0:
        return out
    weight = np.where(np.isnan(values), 0.0, area[None, :])
    order = np.argsort(values, axis=1)  # NaN last
    sorted_v = np.take_along_axis(values, order, axis=1)
    total = weight.sum(axis=1)
    cum = np.cumsum(np.take_along_axis(weight, order, axis=1), axis=1) / np.where(total > 0, total, 1.0)[:, None]
    for j, q in enumerate(qs):
        idx = np.minimum((cum < q).sum(axis=1), values.shape[1] - 1)
        out[j] = np.where(total > 0, np.take_along_axis(sorted_v, idx[:, None], axis=1)[:, 0], np.nan)
    return out


def _observations_source(ds) -> tuple[str, str]:
    """The observations' file and provenance (measured, reconstructed, synthetic) from
    ``attrs["observations"]`` (``"path (provenance)"``); the provenance from the results' own
    ``observations_provenance`` where present (files written before it: the word in brackets, else
    "unstated")."""
    text = str(ds.attrs.get("observations", ""))
    source, _, said = text.rpartition(" (") if text.endswith(")") else (text, "", "")
    return source, ds.attrs.get("observations_provenance") or said.rstrip(")") or "unstated"


def _observed(ax, ds, t, name: str, marker: str, color: str, label: str) -> None:
    """Observations of series ``name`` (:data:`lightfit.inference.observations.SERIES`) with their SDs, if
    any, labelled with their provenance: ``measured PAR above the canopy``, ``synthetic …``."""
    from lightfit.inference.observations import BY_NAME

    s = BY_NAME[name]
    key = f"obs_{s.value}"
    if key in ds and np.isfinite(ds[key].values).any():
        offset = f"obs_{name}_time_offset_s"
        if offset in ds:  # drawn where the model is read for them (between two steps)
            t = t + pd.to_timedelta(ds[offset].values, unit="s")
        ax.errorbar(
            t,
            ds[key].values,
            yerr=ds[f"obs_{s.sd}"].values,
            fmt=marker,
            color=color,
            ms=7,
            mfc="none",  # hollow: a model line under the readings stays visible (filled ones hid it)
            mew=1.5,
            capsize=3,
            label=f"{_observations_source(ds)[1]} {label} (± its SD){_anchored(ds, name, ds[key].values)}",
            zorder=5,
        )


def _anchors(attrs) -> list:
    """The anchor (a dict, or ``None``) of each day of results, from ``attrs["weather_anchor"]``: one
    JSON object, or several days' (:func:`lightfit.replication.concat_days`, where the days' differ)
    ``"; "``-separated in date order, an empty one for a day without (JSON text has no ``"; "``)."""
    text = attrs.get("weather_anchor")
    if not text:
        return [None]
    return [json.loads(piece) if piece else None for piece in str(text).split("; ")]


def _anchored(ds, name: str, values: np.ndarray) -> str:
    """``"; the forcing is scaled to it"`` where a reconstructed forcing was anchored on one of these
    above-canopy PAR readings (model and reading then agree by construction, not as a check). Several
    days' results with their own anchors (a review: json.loads of the joined text raised): each
    day's readings against that day's anchor."""
    anchors = _anchors(ds.attrs)
    if name != "above_canopy_par" or all(a is None for a in anchors):
        return ""
    values = np.asarray(values)
    dates = str(ds.attrs.get("date", "")).split("; ")
    if len(anchors) > 1 and len(dates) == len(anchors) and "day" in ds.coords:
        # one per date of attrs["date"], in its order; each step's date in the "day" coordinate
        day = np.asarray(ds["day"].values).astype(str)
        days = [day == d for d in dates]
    else:  # one anchor for all the steps (or days that cannot be told apart: every anchor against all)
        days = [np.ones(values.shape, bool)] * len(anchors)
    scaled = any(
        a is not None and np.isclose(values[on], a["par_umol_m2_s"], atol=0.01).any() for a, on in zip(anchors, days)
    )
    return "; the forcing is scaled to it" if scaled else ""
