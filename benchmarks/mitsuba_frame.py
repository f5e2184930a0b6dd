"""The frame-level peer: fovjax's Whitted stereo frame against the same frame on Mitsuba 3.

    python benchmarks/mitsuba_frame.py                   # atrium, 2 x 1280x1024, depth 5, SPP 1
    python benchmarks/mitsuba_frame.py --spp 1 4         # each SPP in turn
    python benchmarks/mitsuba_frame.py --quick           # 2 x 320x256
    python benchmarks/mitsuba_frame.py --gaze 0.5 0.5 0.5 0.5 --repeats 5 --json out.json

Renders one stereo frame three ways in one process and prints ms per frame (the median of
--repeats timed frames after a warm-up), rays per frame and Mrays/s of each:
- **Mitsuba full**: Mitsuba 3 (`llvm_ad_rgb`: Embree traversal, Dr.Jit LLVM kernels on every core)
  as a wavefront Whitted integrator written here in Dr.Jit. Mitsuba answers the ray queries
  (`Scene.ray_intersect_preliminary` for the closest hit, `Scene.ray_test` for shadow rays) on a
  mesh of fovjax's vertices and faces; the shading is fovjax's, written in Dr.Jit arrays with
  `dr.gather` on fovjax's material tables (`fovjax.render.scene_arrays`): ambient Ka·ambient,
  emission Ke, per light Kd·(n·l) + Ks·(n·h)^Ns where the shadow ray is unblocked and the light
  is above both the shading and the geometric normal, diffuse textures (bilinear, wrapping),
  smooth normals (interpolated vertex normals, faced to the incoming ray), mirror reflections
  weighted by Kr up to the maximum depth (mirrored about the geometric normal where the smooth
  normal would send them into the surface), misses seeing the environment (constant colour or
  lat-long map, bilinear), NaN/inf samples painted the bad colour, and the box filter over each
  pixel's samples, side by side. The camera rays are fovjax's own
  (`fovjax.render.stereo_sample_rays`: cell centres, as fovjax's un-jittered SPP), in the order
  Mitsuba's own sensor makes a frame's rays (pixel by pixel, each pixel's samples together); the
  ray offset is fovjax's (`RenderConfig.ray_offset` × `scene_scale`). Each depth level is one pass over
  its live rays: trace, shade, trace the shadow rays, add the contributions into the samples,
  and compact the reflection rays (`dr.compress`) for the next level. Timed: rays in (Dr.Jit
  arrays made beforehand) → the side-by-side image evaluated (`dr.eval`, `dr.sync_thread`),
  after a warm-up frame that compiles its kernels (its time, and the warm-up less a frame, are
  printed).
- **fovjax full** (`FoveatedRenderer.render_full`, i.e. `fovjax.render_stereo`, no foveation)
  and **fovjax foveated** (`FoveatedRenderer.render`: `Foveation(fovea_deg=5, periphery_deg=10,
  spp=SPP)` at `--gaze`, off-centre by default; `diagnostics=()`, the image and counts as a
  frame loop asks), one renderer prepared once for both, both un-jittered (key None),
  `--backend` as fovjax's ray-query backend, `--hits` as `RenderConfig.hits` and
  `--integrator` as `RenderConfig.integrator` (the native Whitted loop or the JAX integrator;
  "auto", the default, is the native one on this CPU where the handler builds): the frame's
  `stats.render_seconds` (the compiled program's wall time) and the wall time around the call;
  compile times printed apart. fovjax's Embree scenes use Embree's robust mode (not watertight at
  every vertex: `BVH.with_watertight`), the Mitsuba scene here does not (Mitsuba's default);
  `--not-watertight` renders fovjax's frames without it too (`BVH.with_watertight(False)`).

After the warm-ups the three frames are timed in turn, --repeats rounds, so that all three see the
same momentary load of a shared machine; each row also gives the median wall time of the whole
call and the process CPU time of the frame (every thread's: the work done, which a loaded
machine's waits for a core do not inflate), the minor page faults of the frame (memory it touched
for the first time, which the kernel maps and zeroes: 4 KiB a fault, or up to 2 MiB where malloc
asks for huge pages) and the kernel time it spent. This process runs malloc the way the `fovjax`
program does (fovjax/_startup.py): freed memory kept for the next frame rather than handed back,
so after the first frames there is little fresh memory (FOVJAX_KEEP_MEMORY=0 keeps the system's
default). Then the ratios (fovjax
foveated / Mitsuba full, fovjax full / Mitsuba full; > 1 means slower than Mitsuba; also in CPU
time), the ray counts of Mitsuba against fovjax's full frame (primary, shadow, reflection; they
agree up to ties and float rounding), and the PSNR of Mitsuba's image against fovjax's full frame
(`fovjax.eval.psnr`: sRGB-encoded, clipped, peak 1); 40 dB or more is expected, and below it the
script says where the images differ. `--json PATH` writes every figure with the command, date, git
commit and machine.

Needs Mitsuba 3 (`pip install 'fovjax[bench]'`) and, for its LLVM backend, the system's LLVM
shared library, version 16 or later (Dr.Jit 1.5 needs it for `dr.maximum`/`dr.atan2`; Debian
package libllvm19, or DRJIT_LIBLLVM_PATH=/path/to/libLLVM.so; where Dr.Jit loads an older libLLVM
than one the system has, the message names the newer one). Without either the script prints why
in one line and exits 0.
"""

from __future__ import annotations

import argparse
import datetime
import importlib.util
import json
import math
import os
import platform
import re
import resource
import shlex
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

MITSUBA_VARIANT = "llvm_ad_rgb"
MIN_LLVM = 16
LLVM_HINT = "install Debian package libllvm19, or set DRJIT_LIBLLVM_PATH to a libLLVM.so of version >= 16"
DEFAULT_GAZE = ((0.4, 0.45), (0.4, 0.45))
PSNR_EXPECTED = 40.0


class Unavailable(Exception):
    """Mitsuba cannot run here (the message says why, in one line): `NotInstalled` or
    `CannotStart`."""


class NotInstalled(Unavailable):
    """The mitsuba package (or Dr.Jit, which it imports) is not installed."""


class CannotStart(Unavailable):
    """Mitsuba is installed but did not start: Dr.Jit found no libLLVM, or too old a one, or the
    package failed to import or to set its variant."""


def _installed(module: str) -> bool:
    try:
        return importlib.util.find_spec(module) is not None
    except ValueError:  # in sys.modules as None: imports of it are blocked
        return False


def _last_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[-1] if text else type(exc).__name__


def _system_llvms() -> list[tuple[int, str]]:
    """(major version, path) of each libLLVM shared library the dynamic linker knows
    (`ldconfig -p`), oldest first; empty where that cannot be read."""
    ldconfig = shutil.which("ldconfig") or next(
        (p for p in ("/sbin/ldconfig", "/usr/sbin/ldconfig") if os.path.exists(p)), None
    )
    if ldconfig is None:
        return []
    try:
        listing = subprocess.run([ldconfig, "-p"], capture_output=True, text=True, timeout=10).stdout
    except (OSError, subprocess.SubprocessError):
        return []
    found = set()
    for line in listing.splitlines():
        match = re.match(r"\s*libLLVM[-.](?:so\.)?(\d+)\S*\s.*=>\s*(\S+)", line)
        if match:
            found.add((int(match.group(1)), match.group(2)))
    return sorted(found)


def llvm_hint() -> str:
    """What to do about Dr.Jit's libLLVM: point it at a new enough one the system already has
    (Dr.Jit may pick an older one first), else install one."""
    newer = [path for version, path in _system_llvms() if version >= MIN_LLVM]
    if newer and not os.environ.get("DRJIT_LIBLLVM_PATH"):
        return f"this system has {newer[-1]}: set DRJIT_LIBLLVM_PATH={newer[-1]}"
    return LLVM_HINT


def load_mitsuba():
    """(mitsuba, drjit) with the LLVM variant set; `NotInstalled` where the packages are not
    installed, `CannotStart` where they are but Mitsuba does not start (each naming why)."""
    try:
        import drjit as dr
        import mitsuba as mi
    except ImportError as exc:
        missing = [m for m in ("mitsuba", "drjit") if not _installed(m)]
        if missing:
            raise NotInstalled(
                f"{' and '.join(missing)} not installed (pip install 'fovjax[bench]'): {_last_line(exc)}"
            ) from exc
        raise CannotStart(f"mitsuba is installed but did not import ({_last_line(exc)})") from exc
    try:
        mi.set_variant(MITSUBA_VARIANT)
        ok = dr.has_backend(dr.JitBackend.LLVM)
    except Exception as exc:  # Dr.Jit found no libLLVM: set_variant raises (ImportError, RuntimeError)
        raise CannotStart(f"Dr.Jit's LLVM backend did not load ({_last_line(exc)}): {llvm_hint()}") from exc
    if not ok:
        raise CannotStart(f"Dr.Jit found no libLLVM: {llvm_hint()}")
    version = tuple(dr.detail.llvm_version())
    if version[0] < MIN_LLVM:
        raise CannotStart(f"Dr.Jit loaded libLLVM {'.'.join(map(str, version))}, too old: {llvm_hint()}")
    return mi, dr


# ---- the Whitted integrator on Mitsuba + Dr.Jit ----------------------------------------------


class MitsubaWhitted:
    """fovjax's Whitted integrator (`fovjax/render/_integrator.py`) as a Dr.Jit wavefront, its ray
    queries answered by a Mitsuba scene of the same triangles."""

    def __init__(self, mi, dr, arrays, config, offset):
        self.mi, self.dr = mi, dr
        self.config = config
        self.offset = float(offset)
        f32 = lambda x: np.ascontiguousarray(np.asarray(x, np.float32))  # noqa: E731
        vertices, faces = f32(arrays.vertices), np.ascontiguousarray(np.asarray(arrays.faces, np.uint32))
        mesh = mi.Mesh(
            "fovjax",
            vertex_count=len(vertices),
            face_count=len(faces),
            has_vertex_normals=False,
            has_vertex_texcoords=False,
        )
        params = mi.traverse(mesh)
        params["vertex_positions"] = mi.Float(vertices.ravel())
        params["faces"] = mi.UInt32(faces.ravel())
        params.update()
        self.scene = mi.load_dict({"type": "scene", "mesh": mesh})
        # Tables the shading gathers from (flat, C order).
        self.vertices = mi.Float(vertices.ravel())
        self.faces = mi.UInt32(faces.ravel())
        self.normals = None if arrays.normals is None else mi.Float(f32(arrays.normals).ravel())
        self.uvs = None if arrays.uvs is None else mi.Float(f32(arrays.uvs).ravel())
        self.face_material = mi.UInt32(np.asarray(arrays.face_material, np.uint32))
        for name in ("ka", "kd", "ks", "ke", "kr"):
            setattr(self, name, mi.Float(f32(getattr(arrays, name)).ravel()))
        self.ns = mi.Float(f32(arrays.ns))
        self.texture_index = mi.Int32(np.asarray(arrays.texture, np.int32))
        self.textures = [(mi.Float(f32(t).ravel()), np.shape(t)[0], np.shape(t)[1]) for t in arrays.textures]
        self.ambient = [float(c) for c in np.asarray(arrays.ambient, np.float32)]
        env = f32(arrays.environment)
        self.env_shape = env.shape[:2]
        self.env_constant = [float(c) for c in env[0, 0]] if env.shape[:2] == (1, 1) else None
        self.env = mi.Float(env.ravel())
        from fovjax.scene import POINT_LIGHT

        self.lights = [
            (
                [float(c) for c in position],
                [float(c) for c in color],
                int(kind) == POINT_LIGHT,
            )
            for position, color, kind in zip(
                np.asarray(arrays.light_position, np.float32),
                np.asarray(arrays.light_color, np.float32),
                np.asarray(arrays.light_kind),
                strict=True,
            )
        ]
        dr.eval(self.vertices, self.faces, self.face_material, self.ns, self.texture_index, self.env)

    # -- small vector helpers (as fovjax's `_vec`: zero vectors normalise to zero) --

    def _normalize(self, v):
        dr, mi = self.dr, self.mi
        n2 = dr.dot(v, v)
        return v * dr.select(n2 > 0, dr.rsqrt(dr.select(n2 > 0, n2, 1.0)), mi.Float(0.0))

    def _vec(self, value):
        return self.mi.Vector3f(*value)

    def _bilinear_wrap(self, table, h, w, uv):
        """fovjax's `bilinear_wrap`: row 0 is v = 0, texels centred, wrapping."""
        dr, mi = self.dr, self.mi
        u = dr.select(dr.isfinite(uv.x), uv.x, 0.0)
        v = dr.select(dr.isfinite(uv.y), uv.y, 0.0)
        x, y = u * w - 0.5, v * h - 0.5
        x0, y0 = dr.floor(x), dr.floor(y)
        fx, fy = x - x0, y - y0
        i0 = mi.Int32(x0) % w
        i0 = dr.select(i0 < 0, i0 + w, i0)
        j0 = mi.Int32(y0) % h
        j0 = dr.select(j0 < 0, j0 + h, j0)
        i1, j1 = (i0 + 1) % w, (j0 + 1) % h
        texel = lambda j, i: dr.gather(mi.Vector3f, table, mi.UInt32(j * w + i))  # noqa: E731
        row0 = texel(j0, i0) * (1 - fx) + texel(j0, i1) * fx
        row1 = texel(j1, i0) * (1 - fx) + texel(j1, i1) * fx
        return row0 * (1 - fy) + row1 * fy

    def _environment(self, d):
        """fovjax's `envmap_lookup` (lat-long, bilinear, wrapping in u, clamped in v)."""
        dr, mi = self.dr, self.mi
        if self.env_constant is not None:
            return self._vec(self.env_constant)
        h, w = self.env_shape
        n2 = dr.dot(d, d)
        inv = dr.select(n2 > 0, dr.rsqrt(dr.select(n2 > 0, n2, 1.0)), 0.0)
        dx, dy, dz = d.x * inv, d.y * inv, d.z * inv
        pole = (dx == 0) & (dz == 0)
        theta = dr.atan2(dr.select(pole, 0.0, dx), dr.select(pole, 1.0, dz))
        u = (theta + dr.pi) / (2 * dr.pi)
        v = 0.5 * (1.0 + dr.clip(dy, -1.0, 1.0))
        x, y = u * w - 0.5, (1.0 - v) * h - 0.5
        x0, y0 = dr.floor(x), dr.floor(y)
        fx, fy = x - x0, y - y0
        i0 = mi.Int32(x0) % w
        i0 = dr.select(i0 < 0, i0 + w, i0)
        i1 = (i0 + 1) % w
        j0 = dr.clip(mi.Int32(y0), 0, h - 1)
        j1 = dr.clip(mi.Int32(y0) + 1, 0, h - 1)
        texel = lambda j, i: dr.gather(mi.Vector3f, self.env, mi.UInt32(j * w + i))  # noqa: E731
        top = texel(j0, i0) * (1 - fx) + texel(j0, i1) * fx
        bottom = texel(j1, i0) * (1 - fx) + texel(j1, i1) * fx
        return top * (1 - fy) + bottom * fy

    def _level(self, o, d, weight, spawn, coherent):
        """One depth level on rays (o, unit d, weight): (contribution, next (o, d, weight, alive),
        the shadow rays' `wanted` masks)."""
        dr, mi = self.dr, self.mi
        ray = mi.Ray3f(o, d)
        pi = self.scene.ray_intersect_preliminary(ray, coherent=coherent)
        found = pi.is_valid()
        prim = dr.select(found, pi.prim_index, 0)
        face = dr.gather(mi.Vector3u, self.faces, prim)
        p0 = dr.gather(mi.Vector3f, self.vertices, face.x)
        p1 = dr.gather(mi.Vector3f, self.vertices, face.y)
        p2 = dr.gather(mi.Vector3f, self.vertices, face.z)
        b1, b2 = pi.prim_uv.x, pi.prim_uv.y
        b0 = 1.0 - b1 - b2
        point = b0 * p0 + b1 * p1 + b2 * p2
        n_geo = self._normalize(dr.cross(p1 - p0, p2 - p0))
        sign = dr.select(dr.dot(n_geo, d) > 0, -1.0, 1.0)
        n_geo = n_geo * sign
        if self.normals is None:
            n = n_geo
        else:
            n_raw = (
                b0 * dr.gather(mi.Vector3f, self.normals, face.x)
                + b1 * dr.gather(mi.Vector3f, self.normals, face.y)
                + b2 * dr.gather(mi.Vector3f, self.normals, face.z)
            )
            n_interp = self._normalize(n_raw)
            degenerate = (n_interp.x == 0) & (n_interp.y == 0) & (n_interp.z == 0)
            n = dr.select(degenerate, n_geo, n_interp * sign)
        m = dr.gather(mi.UInt32, self.face_material, prim)
        local = dr.gather(mi.Vector3f, self.ka, m) * self._vec(self.ambient) + dr.gather(
            mi.Vector3f, self.ke, m
        )
        wanted_masks = []
        if self.lights:
            kd = dr.gather(mi.Vector3f, self.kd, m)
            if self.textures:
                if self.uvs is None:
                    uv = mi.Vector2f(0.0, 0.0)
                else:
                    uv = (
                        b0 * dr.gather(mi.Vector2f, self.uvs, face.x)
                        + b1 * dr.gather(mi.Vector2f, self.uvs, face.y)
                        + b2 * dr.gather(mi.Vector2f, self.uvs, face.z)
                    )
                index = dr.gather(mi.Int32, self.texture_index, m)
                factor = mi.Vector3f(1.0)
                for i, (table, h, w) in enumerate(self.textures):
                    factor = dr.select(index == i, self._bilinear_wrap(table, h, w, uv), factor)
                kd = kd * factor
            ks = dr.gather(mi.Vector3f, self.ks, m)
            ns = dr.gather(mi.Float, self.ns, m)
            origin = point + self.offset * n_geo
            for position, color, is_point in self.lights:
                to_light = self._vec(position) - point if is_point else self._vec(position)
                n2 = dr.dot(to_light, to_light)
                distance = dr.select(n2 > 0, dr.sqrt(dr.select(n2 > 0, n2, 1.0)), 0.0)
                l_dir = self._normalize(to_light)
                n_dot_l = dr.dot(n, l_dir)
                wanted = found & (n_dot_l > 0) & (dr.dot(n_geo, l_dir) > 0)
                shadow = mi.Ray3f(origin, l_dir)
                shadow.maxt = distance if is_point else mi.Float(dr.largest(mi.Float))
                blocked = self.scene.ray_test(shadow, coherent, wanted)
                visible = wanted & ~blocked
                half = self._normalize(l_dir - d)
                n_dot_h = dr.dot(n, half)
                specular = dr.select(n_dot_h > 0, dr.power(dr.select(n_dot_h > 0, n_dot_h, 1.0), ns), 0.0)
                term = (kd * dr.select(wanted, n_dot_l, 0.0) + ks * specular) * self._vec(color)
                local = local + dr.select(visible, term, 0.0)
                wanted_masks.append(wanted)
        contribution = dr.select(found, weight * local, weight * self._environment(d))
        if not spawn:
            return contribution, None, wanted_masks
        weight = weight * dr.gather(mi.Vector3f, self.kr, m)
        alive = found & ((weight.x != 0) | (weight.y != 0) | (weight.z != 0))
        reflected = d - 2.0 * dr.dot(d, n) * n
        into = dr.dot(reflected, n_geo) <= 0
        reflected = dr.select(into, d - 2.0 * dr.dot(d, n_geo) * n_geo, reflected)
        return (
            contribution,
            (point + self.offset * n_geo, self._normalize(reflected), weight, alive),
            wanted_masks,
        )

    def prepare(self, origins, directions):
        """Camera rays (2, spp, H, W, 3) as evaluated Dr.Jit arrays, and the resolve's indices
        (made once, before any frame is timed)."""
        dr, mi = self.dr, self.mi
        eyes, spp, h, w, _ = origins.shape

        # Pixel by pixel, a pixel's samples next to each other: the order Mitsuba's own sensor
        # and sampler make a frame's rays in (coherent packets of neighbouring samples).
        def flat(x):
            return np.ascontiguousarray(np.asarray(x, np.float32).transpose(0, 2, 3, 1, 4).reshape(-1, 3).T)

        o, d = flat(origins), flat(directions)
        rays = (mi.Point3f(*(mi.Float(c) for c in o)), mi.Vector3f(*(mi.Float(c) for c in d)))
        # Output pixel (y, x) of the side-by-side image reads eye x // w, pixel (y, x % w), of
        # every sample s: flat sample index (((eye * h + y) * w + x % w) * spp + s.
        j = np.arange(h * eyes * w)
        y, x = j // (eyes * w), j % (eyes * w)
        base = (((x // w) * h + y) * w + x % w) * spp
        layout = [mi.UInt32(np.asarray(base + s, np.uint32)) for s in range(spp)]
        dr.eval(rays, layout)
        return rays, layout, (eyes, spp, h, w)

    def frame(self, prepared):
        """One frame on prepared rays: (image as a Dr.Jit array, evaluated; ray counts)."""
        dr, mi = self.dr, self.mi
        (o, d_raw), layout, (eyes, spp, h, w) = prepared
        d = self._normalize(d_raw)
        finite = lambda v: dr.isfinite(v.x) & dr.isfinite(v.y) & dr.isfinite(v.z)  # noqa: E731
        valid = finite(o) & finite(d_raw) & ((d.x != 0) | (d.y != 0) | (d.z != 0))
        n_primary = dr.count(valid)
        max_depth = self.config.max_depth
        contribution, nxt, wanted = self._level(o, d, mi.Vector3f(1.0), max_depth > 0, True)
        total = contribution
        dr.eval(total, nxt, wanted)
        shadow_counts = [dr.count(x) for x in wanted]
        n_reflection = 0
        target = None
        for depth in range(1, max_depth + 1):
            o, d, weight, alive = nxt
            index = dr.compress(alive)
            n = dr.width(index)
            if n == 0:
                break
            n_reflection += n
            o, d, weight = (dr.gather(type(x), x, index) for x in (o, d, weight))
            target = index if target is None else dr.gather(mi.UInt32, target, index)
            contribution, nxt, wanted = self._level(o, d, weight, depth < max_depth, False)
            dr.scatter_reduce(dr.ReduceOp.Add, total, contribution, target)
            dr.eval(total, target, nxt, wanted)
            shadow_counts += [dr.count(x) for x in wanted]
        bad = ~finite(total)
        sample = dr.select(bad, self._vec(self.config.bad_color), total)
        image = dr.gather(mi.Vector3f, sample, layout[0])
        bad_pixel = dr.gather(mi.Bool, bad, layout[0])
        for s in range(1, spp):
            image = image + dr.gather(mi.Vector3f, sample, layout[s])
            bad_pixel = bad_pixel | dr.gather(mi.Bool, bad, layout[s])
        image = dr.select(bad_pixel, self._vec(self.config.bad_color), image / spp)
        dr.eval(image)
        dr.sync_thread()
        counts = {
            "primary": int(n_primary[0]) if hasattr(n_primary, "__len__") else int(n_primary),
            "shadow": sum(int(c[0]) if hasattr(c, "__len__") else int(c) for c in shadow_counts),
            "reflection": int(n_reflection),
        }
        return image, counts

    def to_numpy(self, image, height, width):
        a = np.asarray(image, np.float32)
        if a.shape[0] == 3 and a.shape[-1] != 3:
            a = a.T
        return a.reshape(height, width, 3)


def render_mitsuba(arrays, rig, *, spp=1, config=None, head_pose=None):
    """One stereo frame of `arrays` (`fovjax.render.SceneArrays`) through `rig` on Mitsuba, as
    `fovjax.render.render_stereo(arrays, rig, spp=spp, config=config, bvh=...)` renders it
    (un-jittered): (side-by-side image (H, 2W, 3) float32, ray counts by kind). Untimed; for
    checks of the integrator on any scene."""
    from fovjax.render import DEFAULT_CONFIG, stereo_sample_rays
    from fovjax.render.internal import scene_scale

    mi, dr = load_mitsuba()
    config = DEFAULT_CONFIG if config is None else config
    integrator = MitsubaWhitted(mi, dr, arrays, config, config.ray_offset * float(scene_scale(arrays)))
    rays = stereo_sample_rays(rig, head_pose, spp, None)
    prepared = integrator.prepare(np.asarray(rays.origins), np.asarray(rays.directions))
    image, counts = integrator.frame(prepared)
    return integrator.to_numpy(image, rig.height, rig.width), counts


# ---- the run -----------------------------------------------------------------------------


def _git_commit() -> str | None:
    try:
        here = Path(__file__).resolve().parent
        out = subprocess.run(
            ["git", "rev-parse", "HEAD"], cwd=here, capture_output=True, text=True, timeout=10
        )
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"],
            cwd=here,
            capture_output=True,
            text=True,
            timeout=10,
        )
        commit = out.stdout.strip() or None
        return f"{commit}+dirty" if commit and dirty.stdout.strip() else commit
    except (OSError, subprocess.SubprocessError):
        return None


def _machine() -> dict:
    info = {"platform": platform.platform(), "python": platform.python_version(), "cpus": os.cpu_count()}
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                info["cpu"] = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return info


def _median_ms(xs):
    return 1000.0 * statistics.median(xs)


def _rays(counts) -> int:
    return int(counts["primary"] + counts["shadow"] + counts["reflection"])


def _fovjax_counts(stats) -> dict:
    return {"primary": stats.primary_rays, "shadow": stats.shadow_rays, "reflection": stats.reflection_rays}


def explain_difference(test, reference, mi_counts, fj_counts) -> list[str]:
    """Where Mitsuba's image differs from fovjax's (for a PSNR below the expected)."""
    from fovjax import linear_to_srgb

    lines = []
    for kind in ("primary", "shadow", "reflection"):
        if mi_counts[kind] != fj_counts[kind]:
            lines.append(
                f"{kind} rays differ: Mitsuba {mi_counts[kind]:,}, fovjax {fj_counts[kind]:,} "
                f"({mi_counts[kind] - fj_counts[kind]:+,})"
            )
    a = linear_to_srgb(np.clip(np.asarray(test, np.float64), 0, 1))
    b = linear_to_srgb(np.clip(np.asarray(reference, np.float64), 0, 1))
    diff = np.abs(a - b).max(axis=-1)
    off = diff > 1.0 / 255.0
    y, x = np.unravel_index(int(np.argmax(diff)), diff.shape)
    lines.append(
        f"{int(off.sum()):,} of {diff.size:,} pixels ({100 * off.mean():.3f}%) differ by more than 1/255 "
        f"(sRGB); largest {diff.max():.3f} at pixel (row {y}, column {x}): Mitsuba "
        f"{np.round(np.asarray(test, np.float64)[y, x], 4).tolist()}, "
        f"fovjax {np.round(np.asarray(reference, np.float64)[y, x], 4).tolist()}"
    )
    if not np.isfinite(np.asarray(test)).all():
        lines.append("Mitsuba's image holds NaN or inf")
    return lines


def run_spp(scene, rig, bvh, config, integrator, args, spp):
    """Every figure of one SPP."""
    import fovjax
    from fovjax.eval import psnr
    from fovjax.foveate import Foveation
    from fovjax.render import stereo_sample_rays

    gaze = ((args.gaze[0], args.gaze[1]), (args.gaze[2], args.gaze[3]))
    h, w = rig.height, rig.width
    out = {"spp": spp, "width": rig.eye_width, "height": rig.eye_height}

    # Both fovjax frames from one renderer, prepared once (scene arrays and BVH on the device,
    # as Mitsuba's scene is built once): a frame then passes only its gaze. Warm-ups first (each
    # compiles), then the three frames in turn, `repeats` rounds, so that all three see the same
    # momentary load of a shared machine.
    foveation = Foveation(fovea_deg=args.fovea[0], periphery_deg=args.fovea[1], spp=spp)
    renderer = fovjax.FoveatedRenderer(scene, rig, foveation, config, bvh=bvh, diagnostics=())

    def full():
        return renderer.render_full()

    t0 = time.perf_counter()
    frame = full()
    out["fovjax_full_first_wall_s"] = time.perf_counter() - t0
    out["fovjax_full_compile_s"] = frame.stats.compile_seconds
    reference = frame.image
    fj_counts = _fovjax_counts(frame.stats)
    runs = {"fovjax_full": full}

    if not args.no_foveated:

        def foveated():
            return renderer.render(gaze)

        t0 = time.perf_counter()
        f = foveated()
        out["fovjax_foveated_first_wall_s"] = time.perf_counter() - t0
        out["fovjax_foveated_compile_s"] = f.stats.compile_seconds
        runs["fovjax_foveated"] = foveated

    # Mitsuba, on fovjax's own camera rays.
    rays = stereo_sample_rays(rig, None, spp, None)
    t0 = time.perf_counter()
    prepared = integrator.prepare(np.asarray(rays.origins), np.asarray(rays.directions))
    out["mitsuba_prepare_s"] = time.perf_counter() - t0
    del rays
    t0 = time.perf_counter()
    image, mi_counts = integrator.frame(prepared)
    out["mitsuba_warmup_s"] = time.perf_counter() - t0
    last = {}

    def mitsuba_full():
        last["mitsuba"] = integrator.frame(prepared)

    runs = {"mitsuba_full": mitsuba_full, **runs}
    timed = {name: {"ms": [], "wall": [], "cpu": [], "faults": [], "sys": []} for name in runs}
    for _ in range(args.repeats):
        for name, fn in runs.items():
            u0 = resource.getrusage(resource.RUSAGE_SELF)
            c0, t0 = time.process_time(), time.perf_counter()
            result = fn()
            wall, cpu = time.perf_counter() - t0, time.process_time() - c0
            u1 = resource.getrusage(resource.RUSAGE_SELF)
            # Memory the frame touched for the first time (minor page faults: pages the kernel
            # had to map and zero, kernel time the frame pays), and that kernel time.
            timed[name]["faults"].append(u1.ru_minflt - u0.ru_minflt)
            timed[name]["sys"].append(u1.ru_stime - u0.ru_stime)
            # fovjax: the compiled program's own time; Mitsuba: its frame (rays in -> image).
            timed[name]["ms"].append(wall if result is None else result.stats.render_seconds)
            timed[name]["wall"].append(wall)
            timed[name]["cpu"].append(cpu)
            if result is not None:
                out[f"{name}_rays"] = _fovjax_counts(result.stats)
    for name, t in timed.items():
        out[f"{name}_ms"] = _median_ms(t["ms"])
        out[f"{name}_wall_ms"] = _median_ms(t["wall"])
        out[f"{name}_cpu_ms"] = _median_ms(t["cpu"])
        out[f"{name}_page_faults"] = statistics.median(t["faults"])
        out[f"{name}_sys_ms"] = _median_ms(t["sys"])
    image, mi_counts = last["mitsuba"]
    out["mitsuba_compile_s"] = max(out["mitsuba_warmup_s"] - out["mitsuba_full_ms"] / 1000, 0.0)
    out["mitsuba_full_rays"] = mi_counts
    test = integrator.to_numpy(image, h, w)
    last.clear()

    value = psnr(test, reference).value
    out["psnr_db"] = value
    out["max_abs_diff_linear"] = float(np.max(np.abs(test - reference)))
    out["rays_agree"] = {k: mi_counts[k] - fj_counts[k] for k in mi_counts}
    if value < PSNR_EXPECTED:
        out["psnr_below_expected"] = explain_difference(test, reference, mi_counts, fj_counts)
    return out


def report(r, args) -> None:
    """The printed table of one SPP."""
    spp, w, h = r["spp"], r["width"], r["height"]
    print(
        f"\nSPP {spp}, 2 x {w}x{h}, max depth {args.max_depth}, "
        f"median of {args.repeats} frames after a warm-up"
    )
    names = [("Mitsuba full", "mitsuba_full"), ("fovjax full", "fovjax_full")]
    if "fovjax_foveated_ms" in r:
        names.append((f"fovjax foveated {args.fovea[0]:g}°/{args.fovea[1]:g}°", "fovjax_foveated"))
    print(
        f"  {'frame':28s} {'ms/frame':>9s} {'wall ms':>9s} {'CPU ms':>9s} {'rays/frame':>11s} "
        f"{'Mrays/s':>8s} {'faults':>9s} {'sys ms':>7s}   primary / shadow / reflection"
    )
    for label, key in names:
        counts, ms = r[f"{key}_rays"], r[f"{key}_ms"]
        n = _rays(counts)
        print(
            f"  {label:28s} {ms:9,.1f} {r[f'{key}_wall_ms']:9,.0f} {r[f'{key}_cpu_ms']:9,.0f} {n:11,} "
            f"{n / ms / 1e3:8.2f} {r[f'{key}_page_faults']:9,.0f} {r[f'{key}_sys_ms']:7,.0f}   "
            f"{counts['primary']:,} / {counts['shadow']:,} / {counts['reflection']:,}"
        )
    ratios, cpu_ratios = [], []
    for label, key in reversed(names[1:]):
        r[f"ratio_{key}_over_mitsuba"] = r[f"{key}_ms"] / r["mitsuba_full_ms"]
        r[f"cpu_ratio_{key}_over_mitsuba"] = r[f"{key}_cpu_ms"] / r["mitsuba_full_cpu_ms"]
        ratios.append(f"{label} / Mitsuba full {r[f'ratio_{key}_over_mitsuba']:.2f}")
        cpu_ratios.append(f"{r[f'cpu_ratio_{key}_over_mitsuba']:.2f}")
    print(
        "  time ratios (> 1: slower than Mitsuba): "
        + "; ".join(ratios)
        + f" (in CPU time: {' and '.join(cpu_ratios)})"
    )
    compile_text = f"fovjax full {r['fovjax_full_compile_s']:.1f} s"
    if "fovjax_foveated_compile_s" in r:
        compile_text += f", foveated {r['fovjax_foveated_compile_s']:.1f} s"
    print(
        f"  compile: {compile_text}; Mitsuba warm-up frame {1000 * r['mitsuba_warmup_s']:,.0f} ms, "
        f"of which ~{1000 * r['mitsuba_compile_s']:,.0f} ms compiling kernels (warm-up - median frame; "
        f"Dr.Jit keeps kernels on disk, so a later run compiles less); rays made in "
        f"{1000 * r['mitsuba_prepare_s']:,.0f} ms, untimed"
    )
    agree = ", ".join(f"{k} {v:+,}" for k, v in r["rays_agree"].items())
    print(f"  rays, Mitsuba - fovjax full: {agree}")
    verdict = "as expected" if r["psnr_db"] >= PSNR_EXPECTED else f"BELOW the expected {PSNR_EXPECTED:g} dB"
    print(
        f"  PSNR of Mitsuba's image against fovjax's full frame: {r['psnr_db']:.1f} dB ({verdict}); "
        f"largest linear difference {r['max_abs_diff_linear']:.3g}"
    )
    for line in r.get("psnr_below_expected", []):
        print(f"    why: {line}")


def main(argv=None) -> dict | None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="atrium", help="a built-in scene (fovjax.scenes.BUILTIN)")
    ap.add_argument("--width", type=int, default=1280, help="pixels per eye")
    ap.add_argument("--height", type=int, default=1024)
    ap.add_argument("--quick", action="store_true", help="2 x 320x256")
    ap.add_argument(
        "--spp", type=int, nargs="+", default=[1], help="samples per pixel, each in turn (1 4 ...)"
    )
    ap.add_argument("--max-depth", type=int, default=5)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--backend", default="auto", help="fovjax's ray-query backend (auto, jax, embree, warp)")
    ap.add_argument(
        "--hits",
        default="recomputed",
        choices=("recomputed", "backend"),
        help="fovjax's RenderConfig.hits: t, u, v recomputed from the vertices (default) or the backend's",
    )
    ap.add_argument(
        "--integrator",
        default="auto",
        choices=("auto", "native", "jax"),
        help="fovjax's RenderConfig.integrator: the native Whitted loop on a CPU ('auto', 'native') or JAX",
    )
    ap.add_argument(
        "--gaze",
        type=float,
        nargs=4,
        default=[*DEFAULT_GAZE[0], *DEFAULT_GAZE[1]],
        metavar=("LX", "LY", "RX", "RY"),
        help="the foveated frame's gaze per eye, normalised display coordinates (default off-centre)",
    )
    ap.add_argument("--fovea", type=float, nargs=2, default=[5.0, 10.0], metavar=("FOVEA", "PERIPHERY"))
    ap.add_argument("--no-foveated", action="store_true", help="skip the foveated frame")
    ap.add_argument(
        "--not-watertight",
        action="store_true",
        help="fovjax's Embree scenes without Embree's robust mode (BVH.with_watertight(False)), as "
        "Mitsuba builds its scene here",
    )
    ap.add_argument("--json", type=Path, default=None, help="write every figure to this JSON file")
    args = ap.parse_args(argv)
    if args.repeats < 1 or args.max_depth < 0 or args.width < 1 or args.height < 1:
        ap.error("--repeats, --width and --height must be positive and --max-depth >= 0")
    bad_spp = [s for s in args.spp if s < 1 or round(s**0.5) ** 2 != s]
    if bad_spp:
        ap.error(f"--spp {bad_spp[0]}: expected a positive square (1, 4, 9, ...), a grid per pixel")
    if args.quick:
        args.width, args.height = 320, 256

    try:
        mitsuba = load_mitsuba()
    except Unavailable as exc:
        print(f"mitsuba_frame: skipped: {exc}")
        return None
    mi, dr = mitsuba

    import jax

    import fovjax
    from fovjax.render import RenderConfig, StereoRig, scene_arrays
    from fovjax.render.internal import bvh_for, scene_scale

    config = RenderConfig(
        max_depth=args.max_depth, backend=args.backend, hits=args.hits, integrator=args.integrator
    )
    scene = fovjax.scenes.BUILTIN[args.scene]()
    rig = StereoRig.from_pose(
        fovjax.scenes.default_camera(scene), eye_width=args.width, eye_height=args.height
    )
    # What fovjax.render_stereo renders: the scene's arrays with the config's background.
    arrays = scene_arrays(scene, background=config.background)
    bvh = bvh_for(scene, None)
    if args.not_watertight:
        bvh = bvh.with_watertight(False)
    t0 = time.perf_counter()
    offset = config.ray_offset * float(scene_scale(arrays))
    integrator = MitsubaWhitted(mi, dr, arrays, config, offset)
    scene_build_s = time.perf_counter() - t0
    dev = jax.devices()[0]
    print(
        f"{args.scene}: {scene.num_triangles:,} triangles, {scene.lights.position.shape[0]} light(s), "
        f"{len(arrays.textures)} texture(s), vertex normals {'yes' if arrays.normals is not None else 'no'}, "
        f"environment {np.shape(arrays.environment)[0]}x{np.shape(arrays.environment)[1]}"
    )
    print(
        f"fovjax on jax {jax.__version__} {dev.platform} ({len(jax.devices())} device(s)), backend "
        f"{args.backend}: {fovjax.trace.describe_backend(args.backend, dev.platform)}"
    )
    print(
        f"Mitsuba {mi.__version__} {MITSUBA_VARIANT} (Dr.Jit {dr.__version__}, libLLVM "
        f"{'.'.join(map(str, dr.detail.llvm_version()))}, {dr.thread_count()} threads)"
    )
    gaze = ((args.gaze[0], args.gaze[1]), (args.gaze[2], args.gaze[3]))
    print(f"foveated: {args.fovea[0]:g}°/{args.fovea[1]:g}° at gaze {gaze}")
    sys.stdout.flush()

    results = []
    for spp in args.spp:
        r = run_spp(scene, rig, bvh, config, integrator, args, spp)
        r["mitsuba_scene_build_s"] = scene_build_s
        r["mitsuba_threads"] = dr.thread_count()
        report(r, args)
        sys.stdout.flush()
        results.append(r)

    record = {
        "benchmark": "mitsuba_frame",
        "command": " ".join(shlex.quote(a) for a in [sys.executable, *sys.argv])
        if argv is None
        else shlex.join(["benchmarks/mitsuba_frame.py", *argv]),
        "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "git_commit": _git_commit(),
        "machine": _machine(),
        "versions": {
            "jax": jax.__version__,
            "mitsuba": mi.__version__,
            "drjit": dr.__version__,
            "libllvm": ".".join(map(str, dr.detail.llvm_version())),
        },
        "scene": args.scene,
        "triangles": int(scene.num_triangles),
        "eye_width": args.width,
        "eye_height": args.height,
        "max_depth": args.max_depth,
        "repeats": args.repeats,
        "backend": args.backend,
        "hits": args.hits,
        "integrator": args.integrator,
        "watertight": not args.not_watertight,
        "glibc_tunables": os.environ.get("GLIBC_TUNABLES", ""),
        "gaze": gaze,
        "fovea_deg": args.fovea,
        "results": results,
    }
    if args.json is not None:
        args.json.write_text(json.dumps(record, indent=2, default=_json_default) + "\n")
        print(f"\nwrote {args.json}")
    return record


def frame_tables(record: dict) -> list[dict]:
    """The record's frames as the Performance page's tables, one per SPP."""
    tables = []
    for r in record["results"]:
        rows = []
        for label, key in (
            ("Mitsuba 3, full", "mitsuba_full"),
            ("fovjax, full", "fovjax_full"),
            ("fovjax, foveated", "fovjax_foveated"),
        ):
            if f"{key}_ms" not in r:
                continue
            n = sum(r[f"{key}_rays"].values())
            ratio = r[f"{key}_ms"] / r["mitsuba_full_ms"]
            rows.append(
                [
                    label,
                    round(r[f"{key}_ms"], 1),
                    round(r[f"{key}_cpu_ms"]),
                    n,
                    round(n / r[f"{key}_ms"] / 1e3, 2),
                    round(ratio, 3),
                    round(r[f"{key}_page_faults"]) if f"{key}_page_faults" in r else "–",
                ]
            )
        tables.append(
            {
                "title": f"{record['scene']}, 2 × {r['width']}×{r['height']}, SPP {r['spp']}, depth "
                f"{record['max_depth']}, backend {record['backend']}, "
                f"hits {record.get('hits', 'recomputed')}, "
                f"integrator {record.get('integrator', 'jax (before the native integrator)')}, "
                f"{'' if record.get('watertight', True) else 'fovjax not watertight, '}"
                f"GLIBC_TUNABLES {record.get('glibc_tunables') or 'unset'}, "
                f"foveated {record['fovea_deg']}° "
                f"at gaze {record['gaze']}; PSNR of Mitsuba's frame against fovjax's full frame "
                f"{r['psnr_db']:.1f} dB",
                "columns": [
                    "frame",
                    "ms per frame",
                    "CPU ms",
                    "rays",
                    "Mrays/s",
                    "time / Mitsuba full",
                    "page faults",
                ],
                "rows": rows,
            }
        )
    return tables


def _json_default(x):
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, float) and not math.isfinite(x):
        return str(x)
    raise TypeError(f"not JSON serialisable: {type(x)}")


if __name__ == "__main__":
    # First, before Mitsuba starts its threads: importing fovjax keeps malloc's freed memory for
    # the next frame (fovjax/_startup.py), for both renderers in this process
    # (FOVJAX_KEEP_MEMORY=0: the system's default).
    from _record import write_record

    import fovjax  # noqa: F401

    figures = main()
    if figures is not None:  # None: skipped (no mitsuba or no libLLVM)
        figures = json.loads(json.dumps(figures, default=_json_default))
        figures["tables"] = frame_tables(figures)
        write_record("mitsuba_frame", figures)
