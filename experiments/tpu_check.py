"""Would triose-phosphate utilisation (TPU) limit the default canopy's photosynthesis?

    python experiments/tpu_check.py [--quick] [--out experiments/results/tpu_check.json]

lightfit's FvCB leaf takes the lesser of the Rubisco- and electron-transport-limited rates; it has
no third, TPU-limited rate (docs/photosynthesis.md). CLM4.5/5 add one (Oleson et al. 2013, CLM4.5
technical note, ch. 8; Collatz et al. 1991): A_p = 3 T_p, with T_p = 0.167 Vcmax25 at 25 °C and a
peaked temperature response (ΔH_a 53.1 kJ mol⁻¹, ΔH_d 150.65 kJ mol⁻¹, ΔS 490 J mol⁻¹ K⁻¹, the
technical note's table 8.2). TPU limits at high CO2 and at low temperature, where the Calvin cycle
outruns the sugar synthesis that recycles its phosphate (Sharkey 1985).

For every blade and daytime step of the main job (or ``--quick``) the blade's photosynthesis is
solved (its capacity through the canopy scaling Vcmax25 and so T_p), and the gross rate
min(A_c, A_j) is compared with A_p. Where A_p is lower, TPU would set the rate, and the net
assimilation would be A_p − R_d whatever the CO2 inside the leaf: with A_p the lesser, the stomata
close a little, the CO2 inside rises and A_c and A_j stay above A_p, so the loss is exactly
min(A_c, A_j) − A_p there under lightfit's hard minimum of the rates (CLM's smoothed
co-limitation would cost some 10–16 % even at margins of 1.06–1.30, not compared here). Cases: the
run's day; 10 K colder at the same relative humidity (a cold April day, 0–12 °C); 800 ppm CO2;
both; and the cold ones again with leaves acclimated to a colder month (Kattge & Knorr's growth
temperature 11 °C, the coldest its fits are applied at, instead of the set's 15 °C: more Jmax per
Vcmax, a different Vcmax(T)). Writes JSON and prints a table.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

import lightfit  # noqa: F401  (before drjit)
from lightfit.precision import use_float64

use_float64()  # lightfit's precision policy, before any JAX array exists

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from leaf_temperature_check import blades, saturation_vapour_pressure_kpa  # noqa: E402
from provenance import wide_console, write_result  # noqa: E402  (commit, cores, load and command with every JSON)
from rich.table import Table  # noqa: E402

from lightfit.constants import ZERO_CELSIUS_K  # noqa: E402
from lightfit.photosynthesis.parameters import growth_temperature  # noqa: E402
from lightfit.photosynthesis.temperature import peaked_arrhenius  # noqa: E402

OUT = Path(__file__).resolve().parent / "results" / "tpu_check.json"
TPU25_PER_VCMAX25 = 0.167  # CLM4.5
HA, HD, DS = 53_100.0, 150_650.0, 490.0  # CLM4.5 table 8.2, T_p


def tpu_umol_m2_s(vcmax25, t_c):
    """T_p (µmol m⁻² s⁻¹) at leaf temperature ``t_c`` (°C): CLM4.5's peaked Arrhenius form, which is
    lightfit's own (Medlyn et al. 2002, eq. 18) with T_p's energies."""
    tk = np.asarray(t_c, float) + ZERO_CELSIUS_K
    return TPU25_PER_VCMAX25 * np.asarray(vcmax25) * np.asarray(peaked_arrhenius(tk, HA, HD, DS, 298.15))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="the quick configuration (default: the main job's)")
    ap.add_argument("--out", type=Path, default=OUT)
    a = ap.parse_args(argv)
    b = blades(a.quick)
    rh = b.e_a / saturation_vapour_pressure_kpa(b.tair)
    lit = b.q > 0
    cold_grown = b.at_growth_temperature(11.0)  # the coldest Kattge & Knorr acclimation (KATTGE_KNORR_RANGE_C)
    cases = {  # name: (air temperature shift K, CO2 ppm or the run's, blades)
        "the run (air T, 400 ppm)": (0.0, None, b),
        "10 K colder": (-10.0, None, b),
        "800 ppm": (0.0, 800.0, b),
        "10 K colder, 800 ppm": (-10.0, 800.0, b),
        "10 K colder, T_g 11 °C": (-10.0, None, cold_grown),
        "10 K colder, 800 ppm, T_g 11 °C": (-10.0, 800.0, cold_grown),
    }
    rows = []
    for name, (dt, co2, cb) in cases.items():
        t = np.broadcast_to(cb.tair + dt, cb.q.shape)
        r = cb.solve(
            t,
            co2=None if co2 is None else np.full_like(cb.co2, co2),
            vpd_kpa=saturation_vapour_pressure_kpa(t) * (1 - rh),
        )
        gross = np.minimum(np.asarray(r.vc_umol_m2_s), np.asarray(r.vj_umol_m2_s))
        a_p = 3.0 * tpu_umol_m2_s(cb.vcmax25_top * cb.capacity, t)
        loss = np.where(lit, np.maximum(gross - a_p, 0.0), 0.0)
        an = np.asarray(r.an_umol_m2_s)
        limited = lit & (a_p < gross)
        day_an = float((an * cb.area).sum())
        t_g = growth_temperature(cb.scenario.photosynthesis, cb.scenario.growth_temperature_c)
        per_step = (loss * cb.area).sum(1) / np.maximum(np.abs((an * cb.area).sum(1)), 1e-12)
        rows.append(
            {
                "case": name,
                "growth_temperature_c": t_g,
                "air_c_range": [float(t.min()), float(t.max())],
                "co2_ppm": float(co2 or cb.co2.mean()),
                "tpu_limited_share_of_lit_blade_steps": float(limited.sum() / lit.sum()),
                "tpu_limited_leaf_area_share_at_worst_step": float(
                    max((limited[k] * cb.area).sum() / cb.area.sum() for k in range(len(t)))
                ),
                "min_ap_over_gross": float(
                    np.min(np.where(lit & (gross > 0), a_p / np.where(gross > 0, gross, 1), np.inf))
                ),
                "day_an_loss": float((loss * cb.area).sum()) / day_an,
                "worst_step_an_loss": float(per_step.max()),
            }
        )
    out = {"config": "quick" if a.quick else "main job", "date": b.date, "vcmax25_top": b.vcmax25_top, "rows": rows}
    a.out.parent.mkdir(parents=True, exist_ok=True)
    write_result(a.out, out)
    t = Table(title=f"would TPU limit? {b.date} ({out['config']}; A_p = 3 T_p, CLM4.5)")
    for c in ("case", "air", "lit blade-steps TPU-limited", "min A_p / min(A_c, A_j)", "day's An lost", "worst step"):
        t.add_column(c, justify="right")
    for r in rows:
        t.add_row(
            r["case"],
            "{:.1f} … {:.1f} °C".format(*r["air_c_range"]),
            f"{100 * r['tpu_limited_share_of_lit_blade_steps']:.2f} %",
            f"{r['min_ap_over_gross']:.3f}",
            f"{100 * r['day_an_loss']:.2f} %",
            f"{100 * r['worst_step_an_loss']:.2f} %",
        )
    wide_console().print(t)
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()
