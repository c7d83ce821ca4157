"""Light: Mitsuba backend choice, scene assembly, leaf BSDF, per-segment irradiance."""
