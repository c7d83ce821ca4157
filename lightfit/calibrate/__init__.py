"""Calibrate: observation model, losses, optimisers, posteriors."""
