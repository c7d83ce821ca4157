"""Photosynthesis: FvCB + stomatal conductance fixed point in JAX."""
