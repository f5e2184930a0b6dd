"""Writing images: PNG (sRGB, 8 bit) and EXR/HDR (linear float)."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def linear_to_srgb(x: np.ndarray) -> np.ndarray:
    """The sRGB transfer function (IEC 61966-2-1) on values clipped to [0, 1]."""
    x = np.clip(np.asarray(x, np.float64), 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)


def save_image(path, image, *, exposure: float = 1.0) -> Path:
    """Save a linear-RGB float image (H, W, 3). `.png`: scaled by `exposure`, clipped to [0, 1]
    (no tone curve beyond the clip), sRGB-encoded, 8 bit. `.exr`/`.hdr`: linear float32."""
    import imageio.v3 as iio

    path = Path(path)
    image = np.asarray(image, np.float32)
    if image.ndim != 3 or image.shape[-1] not in (3, 4):
        raise ValueError(f"save_image: expected an (H, W, 3) image, got shape {image.shape}")
    if not np.isfinite(image).all():
        raise ValueError(f"save_image: {path}: the image contains NaN or inf values")
    path.parent.mkdir(parents=True, exist_ok=True)
    suffix = path.suffix.lower()
    if suffix == ".png":
        rgb8 = np.round(linear_to_srgb(image[..., :3] * exposure) * 255).astype(np.uint8)
        iio.imwrite(path, rgb8)
    elif suffix in (".exr", ".hdr"):
        iio.imwrite(path, image[..., :3])
    else:
        raise ValueError(f"save_image: unknown image format {suffix!r} for {path} (use .png, .exr or .hdr)")
    return path
