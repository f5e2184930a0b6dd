"""Temporal stability of foveated frames: flicker in the periphery over a sequence with moving
gaze, for a fresh sampling key per frame against a fixed one.

Flicker of a sequence is, per frame step t-1 -> t, the mean over a pixel mask of the channel
mean of |I_t - I_{t-1}|, on display-encoded values (clipped to [0, 1] and sRGB-encoded, what the
HMD shows; `transfer="linear"` for linear values). The mask of a region is the pixels that are
in that region in *both* frames (the foveated frame's own region map: `fovea`, `periphery`,
`outside`, and `beyond_fovea` = periphery or outside).

The reference. A full render changes from frame to frame only through its sampling: with a fixed
key and a still head it is the same image every frame (flicker 0), so "the full render under the
same key policy" is no denominator for the fixed-key foveated sequence. The ratio therefore
divides by the flicker of the full render with a fresh key per frame (1-spp jitter: the temporal
noise a viewer of the unfoveated renderer with stochastic anti-aliasing sees), the same
denominator for both policies, so fresh and fixed are compared on one scale. The full render
under the foveated sequence's own policy is recorded too (`full_same_policy_*`): 0 for a fixed
key and a still head, so any fixed-key foveated flicker is the foveation's own — its eccentricity
map and therefore its regions, blocks and sample pattern move with the gaze even when the key
does not.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from pathlib import Path

import jax
import numpy as np

from ._metrics import display_encode
from ._pareto import write_csv

KEY_MODES = ("fresh", "fixed")
FLICKER_REGIONS = ("fovea", "periphery", "outside", "beyond_fovea")


def gaze_sequence(gaze, frames: int, fps: float = 90.0) -> np.ndarray:
    """Per-frame gaze (F, 2, 2) in normalised display coordinates (both eyes) at t = f / fps:
    from a gaze model with `position(t)` (e.g. `fovjax.devices.Scanpath`), a callable
    t -> (x, y), or an array: one point (2,) / ((lx, ly), (rx, ry)) held still, or per frame
    (F, 2) / (F, 2, 2). Every point must be on screen ([0, 1])."""
    if not (isinstance(frames, int | np.integer) and frames >= 2):
        raise ValueError(f"gaze_sequence: frames must be an integer >= 2, got {frames!r}")
    if not (math.isfinite(fps) and fps > 0):
        raise ValueError(f"gaze_sequence: fps must be > 0, got {fps}")
    times = np.arange(frames) / fps
    position = getattr(gaze, "position", None)
    if position is None and callable(gaze):
        position = gaze
    if position is not None:
        g = np.asarray([position(float(t)) for t in times], np.float64)
    else:
        g = np.asarray(gaze, np.float64)
        if g.shape in ((2,), (2, 2)):
            g = np.broadcast_to(g.reshape(-1, 2), (2, 2))
            g = np.broadcast_to(g, (frames, 2, 2))
        elif g.shape not in ((frames, 2), (frames, 2, 2)):
            raise ValueError(
                f"gaze_sequence: a gaze array must be (2,), (2, 2), ({frames}, 2) or ({frames}, 2, 2) "
                f"for {frames} frames, got shape {g.shape}"
            )
    if g.ndim == 2:
        if g.shape != (frames, 2):
            raise ValueError(f"gaze_sequence: the gaze model gave shape {g.shape}, expected ({frames}, 2)")
        g = np.repeat(g[:, None, :], 2, axis=1)
    bad = ~np.isfinite(g).all(axis=(1, 2)) | ((g < 0) | (g > 1)).any(axis=(1, 2))
    if bad.any():
        f = int(np.flatnonzero(bad)[0])
        raise ValueError(
            f"gaze_sequence: frame {f} (t = {times[f]:.4f} s) has gaze {g[f].tolist()}, not finite "
            "normalised coordinates in [0, 1]"
        )
    return np.array(g, np.float32)


def flicker(images, masks=None, *, transfer: str = "srgb") -> np.ndarray:
    """Per frame step (F - 1,): the mean over the pixels in `masks[t] & masks[t - 1]` (all
    pixels without masks) of the channel mean of |I_t - I_{t-1}| on display-encoded values.
    NaN for a step whose mask is empty. `images` (F, H, W, 3) linear RGB; `masks` (F, H, W)."""
    imgs = np.asarray(images, np.float64)
    if imgs.ndim != 4 or imgs.shape[-1] != 3 or imgs.shape[0] < 2:
        raise ValueError(f"flicker: images must be (F >= 2, H, W, 3), got shape {imgs.shape}")
    if not np.isfinite(imgs).all():
        raise ValueError("flicker: images contain NaN or inf values")
    if masks is None:
        m = np.ones(imgs.shape[:3], bool)
    else:
        m = np.asarray(masks)
        if m.shape != imgs.shape[:3]:
            raise ValueError(f"flicker: masks shape {m.shape} differs from the images' {imgs.shape[:3]}")
        m = m.astype(bool)
    enc = display_encode(imgs, transfer)
    diff = np.abs(np.diff(enc, axis=0)).mean(axis=-1)  # (F-1, H, W)
    both = m[1:] & m[:-1]
    n = both.sum(axis=(1, 2))
    total = np.where(both, diff, 0.0).sum(axis=(1, 2))
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > 0, total / np.maximum(n, 1), np.nan)


def region_masks(regions) -> dict[str, np.ndarray]:
    """Masks (…, H, 2W) side by side from a foveated frame's per-eye region maps (…, 2, H, W)."""
    r = np.asarray(regions)
    side = np.concatenate([r[..., 0, :, :], r[..., 1, :, :]], axis=-1)
    return {
        "fovea": side == 0,
        "periphery": side == 1,
        "outside": side == 2,
        "beyond_fovea": side != 0,
    }


class FullRenders:
    """Full (unfoveated) stereo renders of one scene, rig and render config, memoised by
    (key, spp, head pose): cases that need the same reference frame render it once. A key
    of None renders pixel-cell centres (no jitter)."""

    def __init__(self, scene, rig, config=None, bvh=None):
        from ..render import DEFAULT_CONFIG

        self.scene, self.rig, self.bvh = scene, rig, bvh
        self.config = config or DEFAULT_CONFIG
        self._frames: dict = {}

    def frame(self, key: int | None, spp: int = 1, head_pose=None):
        from ..render import render_stereo

        pose = None if head_pose is None else tuple(float(a) for a in np.asarray(head_pose).reshape(-1))
        cache_key = (key, int(spp), pose)
        frame = self._frames.get(cache_key)
        if frame is None:
            frame = render_stereo(
                self.scene,
                self.rig,
                spp=int(spp),
                key=None if key is None else jax.random.key(int(key)),
                head_pose=pose,
                config=self.config,
                bvh=self.bvh,
            )
            self._frames[cache_key] = frame
        return frame

    def image(self, key: int | None, spp: int = 1, head_pose=None) -> np.ndarray:
        return self.frame(key, spp, head_pose).image


@dataclasses.dataclass(frozen=True)
class StabilityResult:
    """`records`: one per key mode and frame step (CSV-writable): the gaze, the gaze step in
    degrees, the foveated flicker per region, the full render's (fresh key, and the same key
    policy as the foveated sequence), their ratio, and pixel counts. `summary`: one per key
    mode, the means over steps and the ratio of the means. `transfer`: the encoding flicker is
    measured on."""

    records: list[dict]
    summary: list[dict]
    transfer: str
    fps: float

    def write(self, out_dir, name: str = "stability") -> dict[str, Path]:
        from ._charts import plot_flicker

        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        return {
            "csv": write_csv(self.records, out / f"{name}.csv"),
            "summary": write_csv(self.summary, out / f"{name}_summary.csv"),
            "chart": plot_flicker(self.records, out / f"{name}.png", summary=self.summary),
        }

    def ratio(self, mode: str, region: str = "beyond_fovea") -> float:
        """The summary ratio (foveated flicker / full fresh-key flicker) of a key mode."""
        for row in self.summary:
            if row["key_mode"] == mode:
                return row[f"ratio_{region}"]
        raise ValueError(
            f"StabilityResult.ratio: no key mode {mode!r} (have {[r['key_mode'] for r in self.summary]})"
        )


def _key_modes(key_modes) -> tuple[str, ...]:
    modes = (key_modes,) if isinstance(key_modes, str) else tuple(key_modes)
    if not modes or any(m not in KEY_MODES for m in modes):
        raise ValueError(f"temporal_stability: key_modes must be among {KEY_MODES}, got {key_modes!r}")
    return modes


def _head_poses(head_poses, frames: int):
    if head_poses is None:
        return [None] * frames
    poses = np.asarray(head_poses, np.float64)
    if poses.shape == (3,):
        poses = np.broadcast_to(poses, (frames, 3))
    if poses.shape != (frames, 3) or not np.isfinite(poses).all():
        raise ValueError(
            f"temporal_stability: head_poses must be (yaw, pitch, roll) or ({frames}, 3) finite degrees, "
            f"got shape {poses.shape}"
        )
    return [tuple(p) for p in poses]


def gaze_step_deg(rig, gazes) -> np.ndarray:
    """Angle (degrees) between consecutive gaze rays of the left eye, (F - 1,)."""
    from ..foveate import eccentricity_angle

    camera = rig.eye_cameras()[0]
    g = np.asarray(gazes, np.float32)[:, 0]
    size = np.array([camera.width, camera.height], np.float32)
    return np.asarray(
        [float(eccentricity_angle(camera, g[t - 1], (g[t] * size)[None])[0]) for t in range(1, len(g))]
    )


def temporal_stability(
    full: FullRenders,
    gaze,
    foveation=None,
    *,
    frames: int = 16,
    fps: float = 90.0,
    key_modes: str | Sequence[str] = KEY_MODES,
    seed: int = 0,
    head_poses=None,
    transfer: str = "srgb",
    progress: Callable[[], None] | None = None,
) -> StabilityResult:
    """Render `frames` foveated stereo frames along `gaze` (see `gaze_sequence`; e.g. a
    `fovjax.devices.Scanpath`) at `fps`, once per key mode — "fresh": frame t uses key
    seed + t; "fixed": every frame uses key seed — and the full render with a fresh key per
    frame (the same keys as "fresh"), and measure flicker per region (see the module
    docstring). `head_poses`: per-frame (yaw, pitch, roll) degrees, or None for a still head.
    `full`: the `FullRenders(scene, rig, config, bvh)` of what to render (shared between
    measurements, it reuses its full frames). `progress`: called once per rendered frame."""
    from ..foveate import Foveation, render_foveated

    modes = _key_modes(key_modes)
    foveation = foveation or Foveation()
    gazes = gaze_sequence(gaze, frames, fps)
    poses = _head_poses(head_poses, frames)
    if not isinstance(full, FullRenders):
        raise TypeError(
            "temporal_stability: the first argument must be a fovjax.eval.FullRenders(scene, rig, config), "
            f"got {type(full).__name__}"
        )
    scene, rig, config = full.scene, full.rig, full.config
    tick = progress or (lambda: None)

    full_fresh = []
    for t in range(frames):
        full_fresh.append(full.image(seed + t, 1, poses[t]))
        tick()
    full_fresh = np.stack(full_fresh)
    steps_deg = gaze_step_deg(rig, gazes)
    records, summary = [], []
    for mode in modes:
        images, regions, rays = [], [], []
        for t in range(frames):
            key = seed + t if mode == "fresh" else seed
            frame = render_foveated(
                scene,
                rig,
                gaze=gazes[t],
                foveation=foveation,
                head_pose=poses[t],
                key=jax.random.key(key),
                config=config,
                bvh=full.bvh,
            )
            images.append(frame.image)
            regions.append(frame.regions)
            rays.append(frame.stats.primary_rays)
            tick()
        images = np.stack(images)
        masks = region_masks(np.stack(regions))
        if mode == "fresh":
            same_policy = full_fresh
        else:
            same_policy = np.stack([full.image(seed, 1, poses[t]) for t in range(frames)])
        per_region = {}
        for region, mask in masks.items():
            per_region[region] = (
                flicker(images, mask, transfer=transfer),
                flicker(full_fresh, mask, transfer=transfer),
                flicker(same_policy, mask, transfer=transfer),
                (mask[1:] & mask[:-1]).sum(axis=(1, 2)),
            )
        for t in range(1, frames):
            row = {
                "key_mode": mode,
                "frame": t,
                "time_s": t / fps,
                "gaze_left_x": float(gazes[t, 0, 0]),
                "gaze_left_y": float(gazes[t, 0, 1]),
                "gaze_right_x": float(gazes[t, 1, 0]),
                "gaze_right_y": float(gazes[t, 1, 1]),
                "gaze_step_deg": float(steps_deg[t - 1]),
                "primary_rays": int(rays[t]),
            }
            for region, (fov, fresh, same, n) in per_region.items():
                row[f"flicker_{region}"] = float(fov[t - 1])
                row[f"full_fresh_flicker_{region}"] = float(fresh[t - 1])
                row[f"full_same_policy_flicker_{region}"] = float(same[t - 1])
                with np.errstate(invalid="ignore", divide="ignore"):
                    row[f"ratio_{region}"] = (
                        float(fov[t - 1] / fresh[t - 1]) if fresh[t - 1] > 0 else math.nan
                    )
                row[f"pixels_{region}"] = int(n[t - 1])
            records.append(row)
        mean_row = {"key_mode": mode, "frames": frames, "fps": fps, "transfer": transfer}
        for region, (fov, fresh, same, _) in per_region.items():
            m_fov, m_fresh, m_same = (
                float(np.nanmean(x)) if np.isfinite(x).any() else math.nan for x in (fov, fresh, same)
            )
            mean_row[f"flicker_{region}"] = m_fov
            mean_row[f"full_fresh_flicker_{region}"] = m_fresh
            mean_row[f"full_same_policy_flicker_{region}"] = m_same
            mean_row[f"ratio_{region}"] = m_fov / m_fresh if m_fresh > 0 else math.nan
        mean_row["mean_gaze_step_deg"] = float(np.mean(steps_deg))
        mean_row["mean_primary_rays"] = float(np.mean(rays))
        summary.append(mean_row)
    return StabilityResult(records, summary, transfer, float(fps))
