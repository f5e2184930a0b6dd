"""Image metrics of a (foveated) frame against a reference frame of the same shape.

Inputs are linear-RGB float images (H, W, 3): one eye, or both eyes side by side (H, 2W, 3).
The HMD is an SDR display: what reaches the eye is the linear value clipped to [0, 1] and
sRGB-encoded (the same transform `fovjax.files.save_image` applies for PNG). So the metrics work
on display-referred values by default:

- PSNR on the sRGB-encoded values (`transfer="srgb"`). Encoded values are roughly perceptually
  uniform, so an error in a dark region counts about as much as the same visible error in a
  bright one; on linear values (`transfer="linear"`) dark-region noise, which is the most visible,
  would be almost free. Peak signal 1.
- SSIM (Wang et al. 2004: K1 = 0.01, K2 = 0.03, an 11×11 Gaussian window with σ = 1.5, dynamic
  range 1) on luminance Y = 0.2126 R + 0.7152 G + 0.0722 B of the clipped linear values,
  sRGB-encoded like the display would encode a grey of that luminance. The map covers the
  windows that lie wholly inside the image ("valid"), as scikit-image's `structural_similarity`
  does with `gaussian_weights=True, sigma=1.5, use_sample_covariance=False, data_range=1`.
- FLIP (NVIDIA's `flip-evaluator`, extra `[flip]`): LDR-FLIP on the sRGB-encoded values at a
  stated pixels-per-degree; `dynamic_range="hdr"` gives HDR-FLIP on the unclipped linear values.
- FovVideoVDP (`pyfvvdp`, extra `[fvvdp]`): the foveated metric with a display model of the rig.

Side-by-side images are measured whole; SSIM and FLIP windows that straddle the seam between the
eyes (the 5 columns either side of it for SSIM) mix the two eyes' pixels.
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Literal, overload

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from ..files import linear_to_srgb

TRANSFERS = ("srgb", "linear")
LUMINANCE_WEIGHTS = (0.2126, 0.7152, 0.0722)  # Rec. 709 / sRGB primaries
SSIM_K1, SSIM_K2 = 0.01, 0.03
SSIM_WINDOW, SSIM_SIGMA = 11, 1.5


class MissingExtraError(ImportError):
    """An optional package needed by a metric is not installed."""


@dataclass(frozen=True)
class MetricValue:
    """One metric's number with its units. `note` says how it was computed; `details` holds
    sub-values (per eye, per ring, parameters used)."""

    name: str
    value: float
    units: str
    note: str = ""
    details: Mapping[str, float] = field(default_factory=dict)

    def __float__(self) -> float:
        return float(self.value)

    def __str__(self) -> str:
        return f"{self.name} = {self.value:.6g} {self.units}"


def _require(module: str, extra: str, what: str):
    import importlib

    try:
        return importlib.import_module(module)
    except ImportError as err:
        raise MissingExtraError(
            f"{what} needs the optional package {module!r}: pip install 'fovjax[{extra}]' ({err})"
        ) from err


def _check_images(test, reference, where: str, *, video: bool = False) -> tuple[np.ndarray, np.ndarray]:
    t = np.asarray(test, np.float64)
    r = np.asarray(reference, np.float64)
    ndims = (3, 4) if video else (3,)
    for name, a in (("test", t), ("reference", r)):
        if a.ndim not in ndims or a.shape[-1] != 3:
            shape = "(H, W, 3) or (F, H, W, 3)" if video else "(H, W, 3)"
            raise ValueError(f"{where}: {name} must be a linear-RGB image {shape}, got shape {a.shape}")
        if not np.isfinite(a).all():
            raise ValueError(f"{where}: {name} contains NaN or inf values")
    if t.shape != r.shape:
        raise ValueError(f"{where}: test shape {t.shape} differs from reference shape {r.shape}")
    return t, r


def _check_transfer(transfer: str, where: str) -> None:
    if transfer not in TRANSFERS:
        raise ValueError(f"{where}: transfer must be one of {TRANSFERS}, got {transfer!r}")


def display_encode(image, transfer: str = "srgb") -> np.ndarray:
    """What the display shows: linear values clipped to [0, 1], then sRGB-encoded (or left
    linear with `transfer="linear"`)."""
    _check_transfer(transfer, "display_encode")
    x = np.clip(np.asarray(image, np.float64), 0.0, 1.0)
    return linear_to_srgb(x) if transfer == "srgb" else x


def luminance(image) -> np.ndarray:
    """Relative luminance Y of linear sRGB-primaries RGB (..., 3) -> (...)."""
    return np.asarray(image, np.float64) @ np.asarray(LUMINANCE_WEIGHTS)


def psnr(test, reference, *, transfer: str = "srgb") -> MetricValue:
    """Peak signal-to-noise ratio in dB over all pixels and channels of the display-encoded
    images (peak 1): 10·log10(1 / MSE); inf when the encoded images are identical."""
    _check_transfer(transfer, "psnr")
    t, r = _check_images(test, reference, "psnr")
    mse = float(np.mean((display_encode(t, transfer) - display_encode(r, transfer)) ** 2))
    value = math.inf if mse == 0.0 else 10.0 * math.log10(1.0 / mse)
    return MetricValue("PSNR", value, "dB", note=f"on {transfer}-encoded values clipped to [0, 1], peak 1")


def gaussian_window(size: int = SSIM_WINDOW, sigma: float = SSIM_SIGMA) -> np.ndarray:
    """1-D Gaussian taps at integer offsets -(size//2)..size//2, normalised to sum 1."""
    if size < 1 or size % 2 == 0:
        raise ValueError(f"gaussian_window: size must be a positive odd number, got {size}")
    if not sigma > 0:
        raise ValueError(f"gaussian_window: sigma must be > 0, got {sigma}")
    x = np.arange(size) - size // 2
    w = np.exp(-(x**2) / (2.0 * sigma**2))
    return w / w.sum()


def _filter_valid(image: np.ndarray, taps: np.ndarray) -> np.ndarray:
    """Separable weighted mean over every window wholly inside the image."""
    n = taps.size
    rows = sliding_window_view(image, n, axis=0) @ taps
    return sliding_window_view(rows, n, axis=1) @ taps


def ssim_map(
    x: np.ndarray, y: np.ndarray, *, window: int = SSIM_WINDOW, sigma: float = SSIM_SIGMA
) -> np.ndarray:
    """SSIM index of two single-channel images with values in [0, 1] (dynamic range 1) at each
    window position wholly inside the image: shape (H - window + 1, W - window + 1)."""
    x = np.asarray(x, np.float64)
    y = np.asarray(y, np.float64)
    if x.shape != y.shape or x.ndim != 2:
        raise ValueError(f"ssim_map: expected two equal 2-D images, got shapes {x.shape} and {y.shape}")
    if min(x.shape) < window:
        raise ValueError(f"ssim_map: image {x.shape} is smaller than the {window}x{window} window")
    taps = gaussian_window(window, sigma)
    mu_x, mu_y = _filter_valid(x, taps), _filter_valid(y, taps)
    var_x = _filter_valid(x * x, taps) - mu_x**2
    var_y = _filter_valid(y * y, taps) - mu_y**2
    cov = _filter_valid(x * y, taps) - mu_x * mu_y
    c1, c2 = SSIM_K1**2, SSIM_K2**2
    num = (2 * mu_x * mu_y + c1) * (2 * cov + c2)
    den = (mu_x**2 + mu_y**2 + c1) * (var_x + var_y + c2)
    return num / den


def ssim(test, reference, *, transfer: str = "srgb") -> MetricValue:
    """Mean SSIM (Wang et al. 2004, Gaussian window 11×11, σ = 1.5) of the luminance of the two
    images, display-encoded (see the module docstring). 1 for identical images; needs H, W >= 11."""
    _check_transfer(transfer, "ssim")
    t, r = _check_images(test, reference, "ssim")
    if min(t.shape[:2]) < SSIM_WINDOW:
        raise ValueError(
            f"ssim: images of {t.shape[:2]} pixels are smaller than the {SSIM_WINDOW}x{SSIM_WINDOW} window"
        )
    yt = display_encode(luminance(np.clip(t, 0.0, 1.0)), transfer)
    yr = display_encode(luminance(np.clip(r, 0.0, 1.0)), transfer)
    value = float(np.mean(ssim_map(yt, yr)))
    return MetricValue("SSIM", value, "dimensionless (1 = identical)", note=f"luminance, {transfer}-encoded")


def pixels_per_degree(width_px: float, fov_deg: float, *, at_deg: float = 0.0) -> float:
    """Pixels per degree of a pinhole display (a flat image plane) `width_px` pixels wide that
    spans `fov_deg` horizontally, at `at_deg` degrees off its optical axis along the horizontal.

    The focal length is f = (W/2) / tan(fov/2) pixels and the pixel position x = f·tan(θ), so
    ppd(θ) = f·(π/180) / cos²(θ). At the centre (θ = 0) ppd = f·π/180: the lowest value on the
    display, because pixels near the edge subtend smaller angles. It is therefore the
    conservative single ppd for FLIP (errors look largest there), and it is below the average
    W / fov (e.g. 1280 px over 90°: 11.17 at the centre against 14.2 on average)."""
    if not width_px > 0:
        raise ValueError(f"pixels_per_degree: width_px must be > 0, got {width_px}")
    if not 0 < fov_deg < 180:
        raise ValueError(f"pixels_per_degree: fov_deg must be in (0, 180), got {fov_deg}")
    if not abs(at_deg) < 90:
        raise ValueError(f"pixels_per_degree: at_deg must be in (-90, 90), got {at_deg}")
    focal_px = (width_px / 2.0) / math.tan(math.radians(fov_deg) / 2.0)
    return focal_px * (math.pi / 180.0) / math.cos(math.radians(at_deg)) ** 2


@overload
def flip(
    test, reference, *, ppd: float, dynamic_range: str = ..., return_map: Literal[False] = ...
) -> MetricValue: ...
@overload
def flip(
    test, reference, *, ppd: float, dynamic_range: str = ..., return_map: Literal[True]
) -> tuple[MetricValue, np.ndarray]: ...
def flip(
    test, reference, *, ppd: float, dynamic_range: str = "ldr", return_map: bool = False
) -> MetricValue | tuple[MetricValue, np.ndarray]:
    """Mean FLIP error (NVIDIA ꟻLIP, `flip-evaluator`; 0 = identical, 1 = maximal) at `ppd`
    pixels per degree (see `pixels_per_degree`; for the rig, `HmdDisplay.ppd`). LDR-FLIP runs on
    the sRGB-encoded, clipped values; HDR-FLIP on the linear values (negatives clipped to 0).
    With `return_map`, also the per-pixel error map (H, W)."""
    if dynamic_range not in ("ldr", "hdr"):
        raise ValueError(f"flip: dynamic_range must be 'ldr' or 'hdr', got {dynamic_range!r}")
    if not (math.isfinite(ppd) and ppd > 0):
        # flip-evaluator calls sys.exit on a bad ppd: check here instead.
        raise ValueError(f"flip: ppd must be a positive number, got {ppd}")
    t, r = _check_images(test, reference, "flip")
    flip_evaluator = _require("flip_evaluator", "flip", "the FLIP metric")
    if dynamic_range == "ldr":
        t_in, r_in = display_encode(t), display_encode(r)
    else:
        t_in, r_in = np.maximum(t, 0.0), np.maximum(r, 0.0)
    error_map, mean, params = flip_evaluator.evaluate(
        np.ascontiguousarray(r_in, np.float32),
        np.ascontiguousarray(t_in, np.float32),
        dynamic_range.upper(),
        inputsRGB=dynamic_range == "ldr",
        applyMagma=False,
        computeMeanError=True,
        parameters={"ppd": float(ppd)},
    )
    value = MetricValue(
        "FLIP",
        float(mean),
        "dimensionless (mean per-pixel error, 0 = identical, 1 = maximal)",
        note=f"{dynamic_range.upper()}-FLIP at {ppd:.3f} pixels per degree",
        details={"ppd": float(ppd)},
    )
    if return_map:
        return value, np.asarray(error_map, np.float64)[..., 0]
    return value


@dataclass(frozen=True)
class RingErrors:
    """Mean per-pixel error in rings of eccentricity [lower_deg, upper_deg). Rings with no
    pixel have `pixels` 0 and a NaN mean."""

    lower_deg: np.ndarray
    upper_deg: np.ndarray
    mean_error: np.ndarray
    pixels: np.ndarray
    error: str
    units: str

    def rows(self) -> list[dict]:
        """One record per ring (CSV-writable)."""
        return [
            {
                "ring_lower_deg": float(lo),
                "ring_upper_deg": float(hi),
                "mean_error": float(m),
                "pixels": int(n),
                "error": self.error,
                "units": self.units,
            }
            for lo, hi, m, n in zip(self.lower_deg, self.upper_deg, self.mean_error, self.pixels, strict=True)
        ]


ERROR_KINDS = ("abs", "squared")


def error_by_eccentricity(
    test,
    reference,
    eccentricity_deg,
    *,
    ring_deg: float = 5.0,
    error: str = "abs",
    transfer: str = "srgb",
    error_map=None,
) -> RingErrors:
    """Mean error per eccentricity ring of `ring_deg` degrees (0–5°, 5–10°, ... up to the
    largest eccentricity in the map). `eccentricity_deg` (H, W) gives each pixel's angle from
    the gaze in degrees (the foveation code's eccentricity map; side by side, the two eyes'
    maps concatenated). The per-pixel error is the channel mean of |test - reference|
    (`error="abs"`) or of its square (`"squared"`) on display-encoded values, or a given
    `error_map` (H, W), e.g. FLIP's."""
    _check_transfer(transfer, "error_by_eccentricity")
    if not (math.isfinite(ring_deg) and ring_deg > 0):
        raise ValueError(f"error_by_eccentricity: ring_deg must be > 0, got {ring_deg}")
    t, r = _check_images(test, reference, "error_by_eccentricity")
    ecc = np.asarray(eccentricity_deg, np.float64)
    if ecc.shape != t.shape[:2]:
        raise ValueError(
            f"error_by_eccentricity: eccentricity map shape {ecc.shape} differs from the image's "
            f"{t.shape[:2]}"
        )
    if not np.isfinite(ecc).all() or (ecc < 0).any():
        raise ValueError("error_by_eccentricity: the eccentricity map must hold finite angles >= 0 (degrees)")
    if error_map is not None:
        per_pixel = np.asarray(error_map, np.float64)
        if per_pixel.shape != t.shape[:2]:
            raise ValueError(
                f"error_by_eccentricity: error_map shape {per_pixel.shape} differs from the image's "
                f"{t.shape[:2]}"
            )
        kind, units = "given error map", "units of the error map"
    elif error in ERROR_KINDS:
        diff = display_encode(t, transfer) - display_encode(r, transfer)
        per_pixel = np.mean(np.abs(diff) if error == "abs" else diff**2, axis=-1)
        kind = (
            f"{'mean absolute' if error == 'abs' else 'mean squared'} difference of "
            f"{'sRGB-encoded' if transfer == 'srgb' else 'linear'} values"
        )
        units = (
            "dimensionless (encoded value, 0-1)"
            if error == "abs"
            else "dimensionless (squared encoded value)"
        )
    else:
        raise ValueError(f"error_by_eccentricity: error must be one of {ERROR_KINDS}, got {error!r}")
    n_rings = max(1, int(math.floor(float(ecc.max()) / ring_deg)) + 1)
    ring = np.minimum((ecc / ring_deg).astype(np.int64), n_rings - 1).ravel()
    pixels = np.bincount(ring, minlength=n_rings)
    sums = np.bincount(ring, weights=per_pixel.ravel(), minlength=n_rings)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(pixels > 0, sums / np.maximum(pixels, 1), np.nan)
    lower = np.arange(n_rings) * ring_deg
    return RingErrors(lower, lower + ring_deg, mean, pixels, kind, units)


@dataclass(frozen=True)
class HmdDisplay:
    """Display model of one eye of the rig for FovVideoVDP: resolution, horizontal field of view
    of the eye's pinhole projection, and photometry (an SDR display with the sRGB transfer; peak
    luminance in cd/m², contrast ratio, ambient illuminance in lux: 0 inside a closed HMD).
    The defaults for photometry are those of pyfvvdp's generic `standard_hmd` (100 cd/m²,
    0.1 cd/m² black); set them for your headset."""

    width_px: int
    height_px: int
    hfov_deg: float
    peak_luminance: float = 100.0
    contrast: float = 1000.0
    ambient_lux: float = 0.0

    def __post_init__(self):
        if int(self.width_px) <= 0 or int(self.height_px) <= 0:
            raise ValueError(f"HmdDisplay: resolution must be positive, got {self.width_px}x{self.height_px}")
        if not 0 < self.hfov_deg < 180:
            raise ValueError(f"HmdDisplay.hfov_deg must be in (0, 180), got {self.hfov_deg}")
        if not self.peak_luminance > 0 or not self.contrast > 1 or self.ambient_lux < 0:
            raise ValueError(
                "HmdDisplay: peak_luminance must be > 0, contrast > 1 and ambient_lux >= 0, got "
                f"{self.peak_luminance}, {self.contrast}, {self.ambient_lux}"
            )

    @classmethod
    def from_camera(cls, camera, **photometry) -> HmdDisplay:
        """The display of one eye from its `fovjax.Camera` (resolution and vertical field of
        view; square pixels), so the metric sees the same geometry the renderer used."""
        tan_half_v = math.tan(math.radians(float(camera.vfov_deg)) / 2.0)
        hfov = 2.0 * math.degrees(math.atan(tan_half_v * camera.width / camera.height))
        return cls(int(camera.width), int(camera.height), hfov, **photometry)

    @property
    def vfov_deg(self) -> float:
        tan_half_h = math.tan(math.radians(self.hfov_deg) / 2.0)
        return 2.0 * math.degrees(math.atan(tan_half_h * self.height_px / self.width_px))

    @property
    def ppd(self) -> float:
        """Pixels per degree at the centre of the eye's display (see `pixels_per_degree`)."""
        return pixels_per_degree(self.width_px, self.hfov_deg)

    def with_resolution(self, width_px: int, height_px: int) -> HmdDisplay:
        """The same field of view and photometry at another resolution (e.g. a reduced render)."""
        return dataclasses.replace(self, width_px=int(width_px), height_px=int(height_px))


JND_JOD = 1.0
"""A just-noticeable difference on FovVideoVDP's JOD scale: a drop of 1 JOD from the reference
(10 JOD) means 75% of observers pick the reference in a two-alternative forced choice, the
usual 2AFC threshold."""


def _gaze_pixels(gaze, n_eyes: int, n_frames: int, width: int, height: int) -> np.ndarray:
    """Gaze in normalised display coordinates -> pyfvvdp fixation points (pixel index whose
    centre is the gaze point), shape (eyes, frames, 2)."""
    g = np.asarray((0.5, 0.5) if gaze is None else gaze, np.float64)
    if g.shape == (2,):
        g = np.broadcast_to(g, (n_eyes, n_frames, 2))
    elif g.shape == (n_eyes, 2):
        g = np.broadcast_to(g[:, None, :], (n_eyes, n_frames, 2))
    elif n_eyes == 1 and g.shape == (n_frames, 2):
        g = g[None]
    elif g.shape == (n_frames, n_eyes, 2):
        g = np.moveaxis(g, 1, 0)
    else:
        raise ValueError(
            f"fovvdp: gaze_xy of shape {g.shape} does not fit {n_eyes} eye(s) and {n_frames} frame(s): "
            "give (x, y), "
            "((lx, ly), (rx, ry)), or per frame (F, 2) / (F, 2, 2)"
        )
    if not np.isfinite(g).all() or (g < 0).any() or (g > 1).any():
        raise ValueError(f"fovvdp: gaze_xy must be finite normalised coordinates in [0, 1], got {g.tolist()}")
    return g * np.array([width, height]) - 0.5


def fovvdp(
    test,
    reference,
    display: HmdDisplay,
    *,
    gaze_xy=None,
    foveated: bool = True,
    fps: float = 0.0,
) -> MetricValue:
    """FovVideoVDP (Mantiuk et al. 2021, `pyfvvdp`, extra `[fvvdp]`, run on the CPU) quality of
    `test` against `reference` in JOD (10 = no visible difference; lower is worse).

    Images are (H, W, 3) or frames (F, H, W, 3) at `fps` frames per second, linear RGB, shown on
    `display` (clipped, sRGB-encoded, then its photometry). W equal to twice the display width
    means both eyes side by side: each eye is measured with its own gaze and the value is the
    lower (worse) eye's, both eyes in `details`. `gaze_xy` is in normalised display coordinates
    (x right, y down, (0, 0) the top-left of each eye's display; default the centre): (x, y),
    ((lx, ly), (rx, ry)), or per frame (F, 2) / (F, 2, 2). With `foveated`, sensitivity falls
    off with eccentricity from the gaze point (FovVideoVDP's foveated mode)."""
    t, r = _check_images(test, reference, "fovvdp", video=True)
    if not isinstance(display, HmdDisplay):
        raise ValueError(f"fovvdp: display must be an HmdDisplay, got {type(display).__name__}")
    if t.ndim == 3:
        t, r = t[None], r[None]
    n_frames, height, width = t.shape[:3]
    if n_frames > 1 and not fps > 0:
        raise ValueError(f"fovvdp: {n_frames} frames need fps > 0, got {fps}")
    if height != display.height_px or width not in (display.width_px, 2 * display.width_px):
        raise ValueError(
            f"fovvdp: images of {width}x{height} pixels do not match the display's {display.width_px}x"
            f"{display.height_px} per eye (or {2 * display.width_px}x{display.height_px} side by side); "
            "use display.with_resolution(...) for a reduced render"
        )
    n_eyes = width // display.width_px
    fixation = _gaze_pixels(gaze_xy, n_eyes, n_frames, display.width_px, height)
    with warnings.catch_warnings():
        # pyfvvdp's bundled loadmat uses a SciPy namespace deprecated since 1.8: not ours to fix.
        warnings.simplefilter("ignore", DeprecationWarning)
        return _fovvdp(t, r, display, fixation, foveated, fps)


def _fovvdp(t, r, display, fixation, foveated, fps) -> MetricValue:
    n_frames, height, width = t.shape[:3]
    n_eyes = width // display.width_px
    # pyfvvdp imports torch: a missing torch surfaces here too, with the extra named.
    pyfvvdp = _require("pyfvvdp", "fvvdp", "FovVideoVDP")
    import torch
    from pyfvvdp.fvvdp_display_model import fvvdp_display_geometry, fvvdp_display_photo_eotf

    geometry = fvvdp_display_geometry((display.width_px, height), fov_horizontal=display.hfov_deg)
    photometry = fvvdp_display_photo_eotf(
        display.peak_luminance, contrast=display.contrast, EOTF="sRGB", E_ambient=display.ambient_lux
    )
    metric = pyfvvdp.fvvdp(
        display_photometry=photometry,
        display_geometry=geometry,
        foveated=foveated,
        quiet=True,
        device=torch.device("cpu"),
    )
    per_eye = []
    for eye in range(n_eyes):
        cols = slice(eye * display.width_px, (eye + 1) * display.width_px)
        t_eye = np.ascontiguousarray(display_encode(t[:, :, cols]), np.float32)
        r_eye = np.ascontiguousarray(display_encode(r[:, :, cols]), np.float32)
        fix = torch.as_tensor(fixation[eye] if n_frames > 1 else fixation[eye, 0], dtype=torch.float32)
        if n_frames == 1:
            jod, _ = metric.predict(t_eye[0], r_eye[0], dim_order="HWC", fixation_point=fix)
        else:
            jod, _ = metric.predict(
                t_eye, r_eye, dim_order="FHWC", frames_per_second=float(fps), fixation_point=fix
            )
        per_eye.append(float(jod))
    names = ("left", "right") if n_eyes == 2 else ("eye",)
    details = {f"jod_{name}": v for name, v in zip(names, per_eye, strict=True)}
    details["ppd"] = display.ppd
    mode = "foveated" if foveated else "non-foveated"
    return MetricValue(
        "FovVideoVDP",
        min(per_eye),
        "JOD (10 = no visible difference)",
        note=f"{mode}, {display.width_px}x{height} per eye over {display.hfov_deg:.1f}° horizontal, "
        f"{display.peak_luminance:g} cd/m² peak" + (", worse eye" if n_eyes == 2 else ""),
        details=details,
    )
