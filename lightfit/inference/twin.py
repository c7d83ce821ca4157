"""Synthetic ("twin") observations: the model at known parameters plus Gaussian noise.

Used to test that calibration and the posterior recover what they should and to expose what they
cannot. The observations are rendered with a *different* random seed than the model being
calibrated, so a twin experiment does not fit its own Monte Carlo noise. Everything produced here
is labelled ``provenance = synthetic``.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping

import numpy as np
import pandas as pd

from lightfit.errors import InputError
from lightfit.inference.observations import BY_NAME
from lightfit.model.coupled import CoupledModel
from lightfit.model.observe import unconverged
from lightfit.model.parameters import Theta, as_theta


def par_sd_relative(rel: float = 0.03) -> Callable[[np.ndarray], np.ndarray]:
    """PAR measurement SD ``max(rel·PAR, 1)`` (µmol m⁻² s⁻¹)."""
    return lambda par: np.maximum(rel * par, 1.0)


def twin_observations(
    model: CoupledModel,
    theta: Theta | Mapping[str, float],
    *,
    render_seed: int,
    noise_seed: int,
    par_sd: Callable[[np.ndarray], np.ndarray] = par_sd_relative(),
    an_sd_umol_m2_s: float = 1.0,
    an_at_night: bool = False,
) -> pd.DataFrame:
    """Observations on the model's steps from ``theta``, rendered with ``render_seed``.

    PAR at the plants gets Gaussian noise of SD ``par_sd(PAR)`` (default 3 %, at least
    1 µmol m⁻² s⁻¹) and is clipped at 0; canopy net CO2 uptake SD ``an_sd_umol_m2_s``; both SDs are
    written with the values. Night steps are missing, except CO2 uptake (respiration) when
    ``an_at_night``. Noise: one standard-normal draw per step for PAR, then one per step for CO2,
    from ``numpy.random.default_rng(noise_seed)``. Refused (InputError naming ``theta``) where the
    leaf photosynthesis did not converge.
    """
    sc = dataclasses.replace(model.scenario, seed=render_seed)
    o = CoupledModel(sc).observe(as_theta(theta))
    n = int(unconverged(o))
    if n:
        raise InputError(
            f"the leaf photosynthesis did not converge for {n} blade-step(s) at the twin's θ "
            f"{as_theta(theta).to_dict()}: observations built on it would be the solver's last iterate",
            parameter="theta",
            expected="parameters inside the model's range (or a SolverConfig with more steps)",
        )
    rng = np.random.default_rng(noise_seed)
    par_s, an_s = BY_NAME["plant_par"], BY_NAME["canopy_an"]
    par = np.asarray(o[par_s.value])
    an = np.asarray(o[an_s.value])
    sd = np.asarray(par_sd(par), float)
    noisy_par = np.clip(par + sd * rng.standard_normal(len(par)), 0.0, None)
    noisy_an = an + an_sd_umol_m2_s * rng.standard_normal(len(an))
    day = model.day
    an_steps = np.ones(len(an), bool) if an_at_night else day
    df = pd.DataFrame(
        {
            par_s.value: np.where(day, noisy_par, np.nan),
            par_s.sd: np.where(day, sd, np.nan),
            an_s.value: np.where(an_steps, noisy_an, np.nan),
            an_s.sd: np.where(an_steps, an_sd_umol_m2_s, np.nan),
        },
        index=model.times,
    )
    df.attrs = {
        "timestamps": model.timestamps,  # the model's values at its steps: what its stamps label
        "provenance": "synthetic",
        "canopy_an_per": model.scenario.an_per,  # the model's area, which the file then says
        "source": f"twin: theta={as_theta(theta).to_dict()}, render_seed={render_seed}, noise_seed={noise_seed}",
    }
    return df


__all__ = ["par_sd_relative", "twin_observations"]
