"""What a scene needs, per region of a foveated frame: the numbers behind a fidelity plan.

`inspect_scene(scene, rig, gaze, foveation, ...)` measures, for one stereo rig, head pose and gaze:

- **Triangles per pixel by eccentricity ring** (5° rings by default), per eye: each triangle
  whose centroid projects inside the eye's image, in front of the camera, is counted in the ring
  of the centroid's eccentricity (as the foveation measures it: angle or planar); the count over
  the ring's pixels (`eccentricity_map`) is the geometric load there. Occluded triangles count too: this is
  what a level of detail removes, not what one frame happens to see.
- **Radiance by reflection depth**: full stereo frames rendered with `max_depth` 0, 1, …, k
  through the public render API; depth d's share is the frame at depth d minus the frame at
  d − 1, summed over a region's pixels and channels, over the depth-k frame's sum there.
- **Radiance by light**: the frame with no lights (ambient and emission only), then with each
  light alone; Whitted shading is a sum over lights (the same reflection paths carry each one),
  so each light's share is its frame minus the unlit one, over the full frame's sum. The unlit
  part is reported as `ambient+emission`.

Regions are the foveation's: fovea (ω <= fovea_deg), periphery (<= periphery_deg), outside.
"""

from __future__ import annotations

import dataclasses
import json

import numpy as np

REGIONS = ("fovea", "periphery", "outside")


@dataclasses.dataclass(frozen=True)
class SceneInspection:
    """The result of `inspect_scene`. `rig`: the stereo rig's field of view (its `fov_axis`),
    IPD, toe-out and the head pose; `rings[i]` = {"lo", "hi" (degrees), "pixels": [left,
    right], "triangles": [left, right], "per_pixel": [left, right]}; `depth_share[region][d]` the
    share of that region's radiance first added at reflection depth d; `light_share[region]`
    maps "ambient+emission" and each light ("light 0", …) to its share; `region_pixels[region]`
    the pixels (both eyes) in each region."""

    scene: str
    triangles: int
    eye_size: tuple[int, int]
    rig: dict
    gaze: tuple[tuple[float, float], tuple[float, float]]
    fovea_deg: float
    periphery_deg: float
    max_depth: int
    spp: int
    rings: tuple[dict, ...]
    region_pixels: dict
    depth_share: dict
    light_share: dict

    def to_json(self) -> str:
        return json.dumps(dataclasses.asdict(self), indent=2)

    def table(self) -> str:
        """The three tables as plain text."""
        w, h = self.eye_size
        lines = [
            f"scene {self.scene}: {self.triangles:,} triangles; eyes {w}x{h}, gaze {self.gaze}, "
            f"fovea {self.fovea_deg:g}°, periphery {self.periphery_deg:g}°, spp {self.spp}",
            "rig: " + ", ".join(f"{k} {v:g}" for k, v in self.rig.items()),
            "",
            "triangles per pixel by eccentricity ring (triangle centroids in view, occluded included)",
            f"{'ring':>10}  {'pixels L':>9} {'pixels R':>9}  {'tris L':>8} {'tris R':>8}  "
            f"{'tri/px L':>8} {'tri/px R':>8}",
        ]
        for r in self.rings:
            ring = f"{r['lo']:g}-{r['hi']:g}°"
            pl, pr = r["pixels"]
            tl, tr = r["triangles"]
            ql, qr = (f"{x:8.3f}" if x is not None else f"{'-':>8}" for x in r["per_pixel"])
            lines.append(f"{ring:>10}  {pl:9d} {pr:9d}  {tl:8d} {tr:8d}  {ql} {qr}")
        lines += ["", f"share of radiance by reflection depth (max depth {self.max_depth})"]
        lines.append(
            f"{'region':>10}  {'pixels':>8}  " + " ".join(f"{f'd{d}':>7}" for d in range(self.max_depth + 1))
        )
        for region in REGIONS:
            shares = " ".join(_share(x) for x in self.depth_share[region])
            lines.append(f"{region:>10}  {self.region_pixels[region]:8d}  {shares}")
        sources = list(next(iter(self.light_share.values())))
        lines += ["", "share of radiance by light"]
        lines.append(f"{'region':>10}  " + " ".join(f"{s:>16}" for s in sources))
        for region in REGIONS:
            lines.append(
                f"{region:>10}  " + " ".join(f"{_share(self.light_share[region][s]):>16}" for s in sources)
            )
        return "\n".join(lines)


def _share(x) -> str:
    return f"{'-':>7}" if x is None else f"{100 * x:6.1f}%"


def _region_of(ecc: np.ndarray, fovea: float, periphery: float) -> np.ndarray:
    return np.where(ecc <= fovea, 0, np.where(ecc <= periphery, 1, 2))


def _shares(parts: list[np.ndarray], total: np.ndarray, region: np.ndarray) -> dict:
    """Per region, each part's sum over the region's pixels over the total's sum there (None
    where the region is empty or dark)."""
    out = {}
    for i, name in enumerate(REGIONS):
        mask = region == i
        denom = float(total[mask].sum()) if mask.any() else 0.0
        out[name] = [float(p[mask].sum()) / denom if denom > 0 else None for p in parts]
    return out


def _eyes(image: np.ndarray) -> np.ndarray:
    """(H, 2W, 3) side by side -> (2, H, W) radiance summed over the channels."""
    h, w2, _ = image.shape
    return np.stack([image[:, : w2 // 2], image[:, w2 // 2 :]]).astype(np.float64).sum(-1)


def inspect_scene(
    scene,
    rig=None,
    gaze=((0.5, 0.5), (0.5, 0.5)),
    foveation=None,
    *,
    head_pose=(0.0, 0.0, 0.0),
    max_depth: int = 3,
    ring_deg: float = 5.0,
    spp: int = 1,
    config=None,
) -> SceneInspection:
    """Measure what `scene` needs per region (module docstring). `rig` defaults to the thesis
    HMD at the scene's default viewpoint; `foveation` to `fovjax.foveate.Foveation()` (its
    fovea/periphery radii and eccentricity mode are used); `config` a `RenderConfig` whose
    `max_depth` is replaced by 0…`max_depth`. Renders `max_depth + 1 + lights + 1` full frames."""
    import jax.numpy as jnp

    from ..foveate import Foveation, check_gaze, eccentricity_angle, eccentricity_map, eccentricity_planar
    from ..render import DEFAULT_CONFIG, RenderConfig, StereoRig, render_stereo, scene_arrays
    from ..scene import Scene, default_camera
    from ..trace import build_bvh

    if not isinstance(scene, Scene):
        raise ValueError(f"inspect_scene: scene must be a fovjax Scene, got {type(scene).__name__}")
    if isinstance(max_depth, bool) or not isinstance(max_depth, int | np.integer) or max_depth < 0:
        raise ValueError(f"inspect_scene: max_depth must be an integer >= 0, got {max_depth!r}")
    if not (np.isfinite(ring_deg) and ring_deg > 0):
        raise ValueError(f"inspect_scene: ring_deg must be a positive number of degrees, got {ring_deg!r}")
    g = check_gaze(gaze, "inspect_scene: gaze")
    foveation = foveation if foveation is not None else Foveation()
    config = config if config is not None else DEFAULT_CONFIG
    if not isinstance(config, RenderConfig):
        raise TypeError(
            f"inspect_scene: config must be a fovjax.render.RenderConfig, got {type(config).__name__}"
        )
    rig = rig if rig is not None else StereoRig.from_pose(default_camera(scene))
    head = np.asarray(head_pose, np.float32)

    # Eccentricity of every pixel, per eye; the region of each.
    cameras = rig.eye_cameras(head)
    ecc = np.stack(
        [np.asarray(eccentricity_map(c, jnp.asarray(g[i]), foveation)) for i, c in enumerate(cameras)]
    )
    region = _region_of(ecc, float(foveation.fovea_deg), float(foveation.periphery_deg))

    # Triangles per pixel by ring.
    edges = np.arange(0.0, float(ecc.max()) + ring_deg, ring_deg)
    centroids = scene.triangles().mean(axis=1)
    pixels, tris = [], []
    for i, cam in enumerate(cameras):
        xy, depth = (np.asarray(a) for a in cam.project(jnp.asarray(centroids)))
        inside = (
            (depth > 0) & (xy[:, 0] >= 0) & (xy[:, 0] < cam.width) & (xy[:, 1] >= 0) & (xy[:, 1] < cam.height)
        )
        at = jnp.asarray(xy[inside])  # the centroid's own eccentricity, not its pixel centre's
        if foveation.eccentricity == "angle":
            tri_ecc = np.asarray(eccentricity_angle(cam, jnp.asarray(g[i]), at))
        else:
            tri_ecc = np.asarray(
                eccentricity_planar(
                    cam, jnp.asarray(g[i]), at, foveation.eye_display_mm, foveation.pixel_pitch_mm
                )
            )
        pixels.append(np.histogram(ecc[i], edges)[0])
        tris.append(np.histogram(tri_ecc, edges)[0])
    rings = tuple(
        {
            "lo": float(edges[j]),
            "hi": float(edges[j + 1]),
            "pixels": [int(pixels[0][j]), int(pixels[1][j])],
            "triangles": [int(tris[0][j]), int(tris[1][j])],
            "per_pixel": [float(tris[e][j] / pixels[e][j]) if pixels[e][j] else None for e in (0, 1)],
        }
        for j in range(len(edges) - 1)
    )

    # Radiance by depth and by light, through the public render API.
    bvh = build_bvh(scene)

    def frame(s, depth):
        arrays = scene_arrays(s, background=config.background)
        cfg = dataclasses.replace(config, max_depth=depth)
        return _eyes(render_stereo(arrays, rig, head_pose=head, spp=spp, config=cfg, bvh=bvh).image)

    by_depth = [frame(scene, d) for d in range(max_depth + 1)]
    total = by_depth[-1]
    depth_parts = [by_depth[0]] + [by_depth[d] - by_depth[d - 1] for d in range(1, max_depth + 1)]
    lights = scene.lights
    n_lights = len(lights)

    def only(idx):
        return Scene(**{**_fields(scene), "lights": lights.take(idx)})

    unlit = frame(only(np.zeros(0, int)), max_depth)
    light_parts = {"ambient+emission": unlit}
    for i in range(n_lights):
        light_parts[f"light {i}"] = frame(only(np.array([i])), max_depth) - unlit
    names = list(light_parts)
    per_light = _shares([light_parts[k] for k in names], total, region)
    return SceneInspection(
        scene=scene.name,
        triangles=scene.num_triangles,
        eye_size=(int(rig.eye_width), int(rig.eye_height)),
        rig={
            "fov_deg": float(rig.fov_deg),
            "ipd_m": float(rig.ipd),
            "toe_out_deg": float(rig.toe_out_deg),
            "head_yaw_deg": float(head[0]),
            "head_pitch_deg": float(head[1]),
            "head_roll_deg": float(head[2]),
        },
        gaze=((float(g[0, 0]), float(g[0, 1])), (float(g[1, 0]), float(g[1, 1]))),
        fovea_deg=float(foveation.fovea_deg),
        periphery_deg=float(foveation.periphery_deg),
        max_depth=int(max_depth),
        spp=int(spp),
        rings=rings,
        region_pixels={name: int((region == i).sum()) for i, name in enumerate(REGIONS)},
        depth_share=_shares(depth_parts, total, region),
        light_share={r: dict(zip(names, per_light[r], strict=True)) for r in REGIONS},
    )


def _fields(scene) -> dict:
    return {f.name: getattr(scene, f.name) for f in dataclasses.fields(scene)}
