"""Inference: observations, one likelihood, gradient calibration, MCMC posteriors, identifiability.

observations (CSV, alignment to a run's steps) → likelihood (Gaussian, measurement + Monte Carlo
SD, noise scale, missing values) → calibration (optimistix BFGS / jaxopt L-BFGS-B), mcmc (priors,
log-posterior, resumable sampler, diagnostics) → posterior (the analysis pipeline),
identifiability (Fisher, profiles); twin makes synthetic observations for tests and experiments.
"""
