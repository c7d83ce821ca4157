"""What matching observations to a run's steps by interval, not by stamp, changes in a light factor.

    python experiments/observation_matching.py [--out experiments/results/observation_matching.json]

A clear day as a logger records it (synthetic, from the reconstruction's assumptions): the 20 April
2016 reconstruction computed minute by minute and averaged into 10-minute means stamped at their
ends (``interval_centres.clear_logger_day``). Those means are the run's steps; the model's
above-canopy sensor equals each step's horizontal PAR exactly (docs/weather.md, "Which PAR lights
the canopy"), so no render is needed and nothing but the matching differs.

Spot readings of a horizontal quantum sensor (a chamber's) are the reconstruction's own 1-minute
values, SD 5 % (the bundled chamber record's 77.47 of 1549.31): one every minute (matched by
interval, a step's ten readings T − 9 … T differ from its mean over (T − 10, T] only by sampling
the minutes, on average 30 s late) and one every 7 minutes (a sparse campaign whose readings fall
at every phase of the intervals). Each campaign
(a window of UTC hours) is matched to the steps twice with
:func:`lightfit.inference.observations.align`: by interval centre (the run's stamps read as ends of
10-min means, what lightfit does now) and by stamp (the stamps read as instants, what it did
before). The light factor that best fits them, f = Σ y m / σ² ÷ Σ m² / σ² over the matched steps
(the analytic optimum of the Gaussian likelihood in f), is 1 when the matching is right, up to
the difference between a 10-minute mean and its minutes. Writes JSON and prints a table.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import pandas as pd
from interval_centres import TEN, clear_logger_day
from rich.table import Table

from lightfit import weather
from lightfit.inference.observations import align, interpolation, read_between
from lightfit.precision import use_float64
from lightfit.weather.timestamps import INSTANTS, Timestamps

use_float64()  # lightfit's precision policy (lightfit.precision), before any JAX array exists

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from provenance import wide_console, write_result  # noqa: E402  (commit, cores, load and command with every JSON)

OUT = Path(__file__).resolve().parent / "results" / "observation_matching.json"
DATE = "2016-04-20"
SD_RELATIVE = 77.47 / 1549.31  # the bundled chamber record's SD
CAMPAIGNS = {  # name: UTC hours [start, end)
    "06-09": (6, 9),
    "10-13": (10, 13),
    "14-17": (14, 17),
    "06-17": (6, 17),
}
EVERY_MIN = (1, 7)
MATCHING = {"interval (now)": Timestamps("end", TEN), "stamp (before)": INSTANTS}
#: runs on instants (the main job's 30-min steps, and 10-min): read between steps, or at the nearest
INSTANT_RUNS = {"30 min": 30, "10 min": 10}
INSTANT_MATCHING = {"interpolated (now)": True, "nearest step (before)": False}


def spot_readings(fine: pd.DataFrame, hours: tuple[int, int], every: int) -> pd.DataFrame:
    """A reading every ``every`` minutes in (start, end] of ``hours`` (UTC; the same half-open
    side as the end-stamped means, so every minute falls in one whole interval), SD 5 %."""
    par = fine["par_umol_m2_s"]
    day = par.index[0].normalize()
    start, end = day + pd.Timedelta(hours=hours[0]), day + pd.Timedelta(hours=hours[1])
    y = par[(par.index > start) & (par.index <= end)].iloc[every // 2 :: every]
    obs = pd.DataFrame(
        {"above_canopy_par_umol_m2_s": y.to_numpy(), "above_canopy_par_sd_umol_m2_s": SD_RELATIVE * y.to_numpy()},
        index=y.index,
    )
    obs.attrs = {"source": f"1-min reconstruction values, {hours[0]:02d}-{hours[1]:02d} UTC", "provenance": "synthetic"}
    return obs


def light_factor(
    obs: pd.DataFrame, steps: pd.DatetimeIndex, model: np.ndarray, stamps: Timestamps, between: bool = True
) -> dict:
    """The analytic optimum f, the RMS relative residual and the steps used; ``between``: the model
    read between two instants as the likelihood reads it (``interpolation``), else at the nearest step."""
    a = align(obs, steps, stamps)
    y, sd = a["above_canopy_par_umol_m2_s"], a["above_canopy_par_sd_umol_m2_s"]
    if between:
        model = read_between(model, *interpolation(obs, steps, stamps)["above_canopy_par_umol_m2_s"])
    ok = np.isfinite(y)
    w = 1.0 / sd[ok] ** 2
    f = float(np.sum(w * y[ok] * model[ok]) / np.sum(w * model[ok] ** 2))
    rel = (y[ok] - model[ok]) / model[ok]
    return {"light_factor": f, "rms_relative_residual": float(np.sqrt(np.mean(rel**2))), "steps": int(ok.sum())}


def cells(row: dict, matching) -> list[str]:
    """A table row's f and RMS residual cells, one pair per matching."""
    return [
        f"{row[m][k]:.4f}" if k == "light_factor" else f"{100 * row[m][k]:.2f} %"
        for m in matching
        for k in ("light_factor", "rms_relative_residual")
    ]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=OUT)
    a = ap.parse_args(argv)
    fine = weather.reconstruct_day(DATE, step="1min")
    logger = clear_logger_day(DATE)
    steps, model = logger.index, logger["par_umol_m2_s"].to_numpy()
    rows = {}
    for every in EVERY_MIN:
        for name, hours in CAMPAIGNS.items():
            obs = spot_readings(fine, hours, every)
            row = {"every_min": every, "campaign": name, "readings": len(obs)}
            rows[f"{name}, every {every} min"] = row | {
                m: light_factor(obs, steps, model, s, between=False) for m, s in MATCHING.items()
            }
    instants = {}
    for run, minutes in INSTANT_RUNS.items():  # the reconstruction's own instants as the run's steps
        at = fine.iloc[::minutes]
        for every in EVERY_MIN:
            for name, hours in CAMPAIGNS.items():
                obs = spot_readings(fine, hours, every)
                row = {"run_step": run, "every_min": every, "campaign": name, "readings": len(obs)}
                instants[f"{run} run, {name}, every {every} min"] = row | {
                    m: light_factor(obs, at.index, at["par_umol_m2_s"].to_numpy(), INSTANTS, between=b)
                    for m, b in INSTANT_MATCHING.items()
                }
    out = {
        "date": DATE,
        "forcing": logger.attrs["source"] + " (synthetic)",
        "readings": "the reconstruction's 1-min PAR, one every 1 or 7 minutes, SD 5 %",
        "model": "the steps' horizontal PAR (the above-canopy sensor, light factor 1)",
        "campaigns": rows,
        "instant_runs": {
            "forcing": "20 April reconstruction at its own instants every 10 or 30 min (synthetic)",
            "matching": "instants between two steps read by linear interpolation in time (now) or at the nearest step",
            "campaigns": instants,
        },
    }
    a.out.parent.mkdir(parents=True, exist_ok=True)
    write_result(a.out, out)
    t = Table(title=f"light factor fitted to spot PAR readings, {DATE} (clear, synthetic logger day)")
    t.add_column("campaign (UTC)")
    t.add_column("every", justify="right")
    t.add_column("readings", justify="right")
    for m in MATCHING:
        t.add_column(f"f, by {m}", justify="right")
        t.add_column(f"RMS resid., by {m}", justify="right")
    for r in rows.values():
        t.add_row(r["campaign"], f"{r['every_min']} min", str(r["readings"]), *cells(r, MATCHING))
    wide_console().print(t)
    t = Table(title="the same readings against runs on instants: read between two steps, or at the nearest")
    for c in ("run step", "campaign (UTC)", "every", "readings"):
        t.add_column(c, justify="right")
    for m in INSTANT_MATCHING:
        t.add_column(f"f, {m}", justify="right")
        t.add_column(f"RMS resid., {m}", justify="right")
    for r in instants.values():
        head = (r["run_step"], r["campaign"], f"{r['every_min']} min", str(r["readings"]))
        t.add_row(*head, *cells(r, INSTANT_MATCHING))
    wide_console().print(t)
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()
