"""Exposure, tone mapping and the clipped-leaf metric.

A camera turns HDR radiance L (W m⁻² sr⁻¹ per channel) into pixel values v = clip(g·L, 0, 1)
with a gain g set by its exposure mode (see :class:`~lightfit.dataset.camera.Camera`), then
applies the sRGB transfer curve and quantises to 8 bits. Where g·L ≥ 1 in any channel the pixel
is *clipped*: two leaves with different light absorption give the same colour, the loss of
information the reference paper warns about for over-lit scenes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lightfit.dataset.camera import Camera

#: Rec. 709 / sRGB luminance weights of linear R, G, B.
LUMA = np.array([0.2126, 0.7152, 0.0722])
#: Average-metering target: mean scene luminance maps to 18 % grey.
MIDDLE_GREY = 0.18


@dataclass(frozen=True)
class Exposure:
    """Result of metering one image.

    Attributes:
        gain: multiplier from radiance (W m⁻² sr⁻¹) to linear pixel value (1 = white).
        metered_luminance: radiance the gain was set from (W m⁻² sr⁻¹): mean luminance in
            ``scene`` mode, the percentile of the brightest channel over leaf pixels in ``leaf``
            mode; NaN in ``fixed`` mode.
        clipped_leaf_fraction: share of leaf pixels with any channel ≥ 1 after the gain;
            NaN when the image shows no leaf.
        leaf_pixels: number of leaf pixels.
        dark: True when the metered region was black (night): the gain then falls back to 1.
        metering: what the gain was set from: ``"leaf"``, ``"scene"``, ``"fixed"``, or ``"scene (no
            leaf in view)"`` where ``leaf`` mode had no leaf pixel to meter.
    """

    gain: float
    metered_luminance: float
    clipped_leaf_fraction: float
    leaf_pixels: int
    dark: bool
    metering: str

    def to_dict(self) -> dict:
        return {k: (None if isinstance(v, float) and not np.isfinite(v) else v) for k, v in self.__dict__.items()}


def luminance(radiance: np.ndarray) -> np.ndarray:
    """(H, W) luminance of an (H, W, C) image: Rec. 709 weights for C = 3, the channel for C = 1."""
    if radiance.shape[-1] == 1:
        return radiance[..., 0]
    return radiance @ LUMA.astype(radiance.dtype)


def meter(radiance: np.ndarray, leaf_mask: np.ndarray, cam: Camera) -> Exposure:
    """Set the gain of ``cam``'s exposure mode on this image and measure clipping on leaves."""
    y = luminance(radiance).astype(np.float64)
    comp = 2.0**cam.exposure_ev
    metering = cam.exposure_mode
    if metering == "leaf" and not leaf_mask.any():
        # Nothing to meter on: the scene's average, not a gain of 1 per W m⁻² sr⁻¹, which left an
        # image of sunlit soil or sky white and called it dark (a review).
        metering = "scene (no leaf in view)"
    if metering == "fixed":
        metered, base = float("nan"), 1.0
    elif metering != "leaf":  # "scene", or leaf mode without leaves
        metered = float(y.mean())
        base = MIDDLE_GREY / metered if metered > 0 else None
    else:  # "leaf": highlight-preserving metering on leaf pixels only
        # Meter the brightest channel, the one that clips first (green, for leaves): then
        # about (100 − percentile) % of leaf pixels clip at 0 EV.
        peak = radiance.max(axis=-1).astype(np.float64)
        metered = float(np.percentile(peak[leaf_mask], cam.meter_percentile))
        base = 1.0 / metered if metered > 0 else None
    dark = base is None
    gain = comp * (1.0 if dark else base)
    return Exposure(gain, metered, clipped_fraction(radiance, leaf_mask, gain), int(leaf_mask.sum()), dark, metering)


def clipped_fraction(radiance: np.ndarray, mask: np.ndarray, gain: float) -> float:
    """Share of ``mask`` pixels whose largest channel reaches 1 after ``gain``; NaN for an empty mask."""
    if not mask.any():
        return float("nan")
    return float((radiance[mask].max(axis=-1) * gain >= 1.0).mean())


def srgb_encode(linear: np.ndarray) -> np.ndarray:
    """sRGB transfer curve (IEC 61966-2-1) of linear values in [0, 1]."""
    return np.where(linear <= 0.0031308, 12.92 * linear, 1.055 * np.power(linear, 1.0 / 2.4) - 0.055)


def tone_map(radiance: np.ndarray, gain: float) -> np.ndarray:
    """8-bit sRGB image (H, W, C) uint8: clip(gain·L, 0, 1), sRGB curve, rounded."""
    v = np.clip(radiance.astype(np.float64) * gain, 0.0, 1.0)
    return np.round(srgb_encode(v) * 255.0).astype(np.uint8)


def write_png(image_u8: np.ndarray, path) -> None:
    """Write an (H, W, 1|3) uint8 image as greyscale or RGB PNG."""
    from PIL import Image

    img = image_u8[..., 0] if image_u8.shape[-1] == 1 else image_u8
    Image.fromarray(np.ascontiguousarray(img)).save(path)


def write_exr(radiance: np.ndarray, path) -> None:
    """Write float32 HDR radiance as OpenEXR through Mitsuba's Bitmap (any variant will do)."""
    from lightfit.light.backend import mitsuba

    mi = mitsuba()
    mi.Bitmap(np.ascontiguousarray(radiance, dtype=np.float32)).write(str(path))
