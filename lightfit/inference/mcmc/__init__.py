"""Bayesian posteriors with emcee: priors, log-posterior, resumable HDF5 backend, diagnostics, sampler.

One file per concept: :mod:`.priors`, :mod:`.log_posterior`, :mod:`.backend`, :mod:`.diagnostics`,
:mod:`.sampler`. The likelihood itself is :mod:`lightfit.inference.likelihood`.
"""

from lightfit.inference.mcmc.backend import ResumableHDFBackend, jsonable, load_run, write_group
from lightfit.inference.mcmc.diagnostics import StopRule, diagnostics, flat_samples, split_rhat, summarize
from lightfit.inference.mcmc.log_posterior import LogPosterior
from lightfit.inference.mcmc.priors import (
    NOISE_SCALE,
    PRIOR_SETS,
    PRIORS_INFORMED,
    PRIORS_WIDE,
    SAMPLED,
    Prior,
    check_sampled,
    priors_table,
)
from lightfit.inference.mcmc.sampler import SamplerResult, check_max_steps, check_run_size, sample

__all__ = [
    "LogPosterior",
    "NOISE_SCALE",
    "PRIORS_INFORMED",
    "PRIORS_WIDE",
    "PRIOR_SETS",
    "Prior",
    "ResumableHDFBackend",
    "SAMPLED",
    "SamplerResult",
    "StopRule",
    "check_max_steps",
    "check_run_size",
    "check_sampled",
    "diagnostics",
    "flat_samples",
    "jsonable",
    "load_run",
    "priors_table",
    "sample",
    "split_rhat",
    "summarize",
    "write_group",
]
