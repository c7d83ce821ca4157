"""Synthetic ("twin") observations: the model at known parameters plus Gaussian noise.

Used to test that calibration recovers what it should and to expose what it cannot. The
observations are rendered with a *different* random seed than the model being calibrated, so a
twin experiment does not fit its own Monte Carlo noise. Everything produced here is labelled
``provenance = synthetic``.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pandas as pd

from lightfit.model.coupled import DEFAULT_THETA, CoupledModel


def twin_observations(
    model: CoupledModel,
    theta: dict,
    *,
    render_seed: int,
    noise_seed: int,
    par_sd_rel: float = 0.03,
    an_sd_umol_m2_s: float = 1.0,
) -> pd.DataFrame:
    """Observations on the model's daytime steps from ``theta``, rendered with ``render_seed``.

    PAR gets Gaussian noise of SD ``par_sd_rel``·PAR (at least 1 µmol m⁻² s⁻¹), net CO2 uptake
    SD ``an_sd_umol_m2_s``; both SDs are written with the values. Night steps are left missing.
    """
    sc = dataclasses.replace(model.scenario, seed=render_seed)
    twin = CoupledModel(sc)
    o = twin.observe({**DEFAULT_THETA, **theta})
    rng = np.random.default_rng(noise_seed)
    par = np.asarray(o["par_umol_m2_s"])
    an = np.asarray(o["an_umol_m2_s"])
    par_sd = np.maximum(par_sd_rel * par, 1.0)
    df = pd.DataFrame(
        {
            "par_umol_m2_s": par + rng.normal(0.0, par_sd),
            "par_sd_umol_m2_s": par_sd,
            "an_umol_m2_s": an + rng.normal(0.0, an_sd_umol_m2_s, len(an)),
            "an_sd_umol_m2_s": an_sd_umol_m2_s,
        },
        index=model.times,
    )
    df.loc[~model.day, :] = np.nan
    df.attrs = {
        "provenance": "synthetic",
        "source": f"twin: theta={theta}, render_seed={render_seed}, noise_seed={noise_seed}",
    }
    return df
