"""lightfit: differentiable light and photosynthesis for wheat canopies.

Data flows one way: ``weather`` -> ``plant`` -> ``light`` -> ``photosynthesis`` -> ``calibrate``.
"""

__version__ = "0.1.0"
