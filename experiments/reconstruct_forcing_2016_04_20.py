"""Write the bundled reconstructed forcing for 2016-04-20 at Selhausen.

    python experiments/reconstruct_forcing_2016_04_20.py [--out data/weather/...csv]

Deterministic: the same lightfit and pvlib versions give the same file byte for byte
(tests/test_weather_bundled.py checks the bundled file against a fresh reconstruction: the
header exactly, the values to 8 significant digits).
Every assumption is a field of lightfit.weather.Anchor / DayAssumptions and is written
into the file's metadata header; data/README.md explains them.
"""

from __future__ import annotations

import argparse
from dataclasses import asdict
from pathlib import Path

from lightfit.precision import use_float64
from lightfit.weather import Anchor, DayAssumptions, reconstruct_day, write_lightfit_csv

use_float64()  # lightfit's precision policy (lightfit.precision), before any JAX array exists

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_OUT = ROOT / "data" / "weather" / "selhausen_2016-04-20_reconstructed.csv"
WRITTEN = ["ghi_w_m2", "par_umol_m2_s", "diffuse_w_m2", "tair_c", "rh", "pair_kpa", "co2_ppm"]


def main(out: Path = DEFAULT_OUT) -> Path:
    anchor, assumptions = Anchor(), DayAssumptions()
    df = reconstruct_day("2016-04-20", anchor=anchor, assumptions=assumptions)
    meta = {
        "provenance": "reconstructed",
        "title": "Selhausen 2016-04-20, RECONSTRUCTED forcing "
        "(clear-sky physics anchored on one chamber point; not a measurement)",
        "site": "Selhausen field minirhizotron facility, 50.865 N, 6.447 E, 103 m",
        "generator": "experiments/reconstruct_forcing_2016_04_20.py (lightfit.weather.reconstruct_day)",
        "anchor": str(asdict(anchor)),
        "assumptions": str(asdict(assumptions)),
        "clear_sky_scale": f"{df.attrs['clear_sky_scale']:.6f}",
        "columns": "time_utc (UTC), ghi_w_m2 (W m-2), par_umol_m2_s (umol m-2 s-1), "
        "diffuse_w_m2 (W m-2, the clear sky's diffuse part), tair_c (degC), rh (0-1), pair_kpa (kPa), co2_ppm (ppm)",
    }
    return write_lightfit_csv(df[WRITTEN], out, meta)


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT)
    print(main(ap.parse_args().out))
