"""Inference: observations, likelihood, gradient calibration, MCMC posteriors, identifiability."""
