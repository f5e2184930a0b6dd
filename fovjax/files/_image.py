"""Reading and writing images: PNG (sRGB, 8 bit, tone-mapped) and EXR/HDR (linear float).

PNG output is display-referred: the linear image is scaled by `exposure`, tone-mapped (`"clip"`:
values above 1 are clipped, the OptiX/thesis behaviour and the default; `"reinhard"`: each
channel x becomes x / (1 + x), which keeps highlights from burning out), then sRGB-encoded
(IEC 61966-2-1) and quantised to 8 bits. EXR (OpenEXR, float32) and HDR (Radiance RGBE) keep
the linear values as rendered; they go through imageio's OpenCV plugin (the `hdr` extra,
`opencv-python-headless`), as do `.exr`/`.hdr` files read by `load_image`.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ._atomic import atomic_path

# OpenCV reads and writes OpenEXR only when this is set before cv2 is imported.
os.environ.setdefault("OPENCV_IO_ENABLE_OPENEXR", "1")

TONEMAPS = ("clip", "reinhard")
HDR_SUFFIXES = (".exr", ".hdr")


def linear_to_srgb(x: np.ndarray) -> np.ndarray:
    """The sRGB transfer function (IEC 61966-2-1) on values clipped to [0, 1]."""
    x = np.clip(np.asarray(x, np.float64), 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)


def srgb_to_linear(x: np.ndarray) -> np.ndarray:
    """The inverse sRGB transfer function, for values in [0, 1]."""
    x = np.clip(np.asarray(x, np.float64), 0.0, 1.0)
    return np.where(x <= 0.04045, x / 12.92, np.power((x + 0.055) / 1.055, 2.4))


def tonemap(image: np.ndarray, *, exposure: float = 1.0, curve: str = "clip") -> np.ndarray:
    """Linear RGB to display values in [0, 1] (before the sRGB encoding): scale by `exposure`,
    then `curve` ("clip" or "reinhard", see the module docstring)."""
    if curve not in TONEMAPS:
        raise ValueError(f"tonemap: curve must be one of {TONEMAPS}, got {curve!r}")
    x = np.maximum(np.asarray(image, np.float64) * exposure, 0.0)
    if curve == "reinhard":
        x = x / (1.0 + x)
    return np.clip(x, 0.0, 1.0)


def _opencv_plugin(path: Path, action: str):
    try:
        import cv2
    except ImportError as err:
        raise ValueError(
            f"{action} {path}: {path.suffix} files need OpenCV (pip install 'fovjax[hdr]', "
            "which installs opencv-python-headless)"
        ) from err
    return cv2


def save_image(path, image, *, exposure: float = 1.0, tonemap_curve: str = "clip") -> Path:
    """Save a linear-RGB float image (H, W, 3). `.png`: `tonemap(image, exposure, curve)` then
    sRGB, 8 bit. `.exr`/`.hdr`: linear float32, unscaled."""
    import imageio.v3 as iio

    path = Path(path)
    image = np.asarray(image, np.float32)
    if image.ndim != 3 or image.shape[-1] not in (3, 4):
        raise ValueError(f"save_image: expected an (H, W, 3) image, got shape {image.shape}")
    if not np.isfinite(image).all():
        raise ValueError(f"save_image: {path}: the image contains NaN or inf values")
    suffix = path.suffix.lower()
    if suffix not in (".png", *HDR_SUFFIXES):
        raise ValueError(f"save_image: unknown image format {suffix!r} for {path} (use .png, .exr or .hdr)")
    path.parent.mkdir(parents=True, exist_ok=True)
    # Written under a temporary name and renamed: the file is complete or absent.
    with atomic_path(path) as tmp:
        if suffix == ".png":
            display = tonemap(image[..., :3], exposure=exposure, curve=tonemap_curve)
            rgb8 = np.round(linear_to_srgb(display) * 255).astype(np.uint8)
            iio.imwrite(tmp, rgb8)
        else:
            _opencv_plugin(path, "save_image:")
            iio.imwrite(tmp, np.ascontiguousarray(image[..., :3]), plugin="opencv")
    return path


def load_image(path) -> np.ndarray:
    """Read an image as linear-RGB float32 (H, W, 3), row 0 the top of the picture.

    `.exr`/`.hdr` are taken as linear; 8- and 16-bit formats (PNG, JPEG, ...) as sRGB-encoded
    and decoded to linear. Grey images are repeated into three channels; alpha is dropped."""
    import imageio.v3 as iio

    path = Path(path)
    if not path.is_file():
        raise ValueError(f"load_image: {path}: no such file")
    suffix = path.suffix.lower()
    try:
        if suffix in HDR_SUFFIXES:
            cv2 = _opencv_plugin(path, "load_image:")
            data = iio.imread(path, plugin="opencv", flags=cv2.IMREAD_UNCHANGED)
        else:
            data = iio.imread(path)
    except ValueError:
        raise
    except Exception as err:  # imageio raises many kinds; name the file
        raise ValueError(f"load_image: {path}: cannot read the image ({err})") from err
    data = np.asarray(data)
    if data.ndim == 2:
        data = data[..., None]
    if data.ndim != 3 or data.shape[-1] not in (1, 2, 3, 4):
        raise ValueError(f"load_image: {path}: expected an image, got an array of shape {data.shape}")
    channels = data.shape[-1]
    rgb = data[..., :3] if channels >= 3 else np.repeat(data[..., :1], 3, axis=-1)
    if np.issubdtype(rgb.dtype, np.integer):
        rgb = srgb_to_linear(rgb.astype(np.float64) / np.iinfo(rgb.dtype).max)
    rgb = np.asarray(rgb, np.float32)
    if not np.isfinite(rgb).all():
        raise ValueError(f"load_image: {path}: the image contains NaN or inf values")
    return rgb
