"""`RenderConfig`: the static settings of the Whitted integrator (one compiled program each)."""

from __future__ import annotations

import dataclasses

import numpy as np

from ..trace import backend_names

# The thesis's defaults: OptiX max trace depth 5, background ("bg color") (0.34, 0.55, 0.85),
# exception colour ("bad color") (1, 0, 1).
THESIS_BACKGROUND = (0.34, 0.55, 0.85)
MAGENTA = (1.0, 0.0, 1.0)
# Where a hit's t, u, v come from (`RenderConfig.hits`).
HITS = ("recomputed", "backend")
# Who runs the integrator's per-ray work (`RenderConfig.integrator`).
INTEGRATORS = ("auto", "native", "jax")
# The specular term of the local shading (`RenderConfig.specular`).
SPECULARS = ("blinn-phong", "phong")
# The luminance weights of `RenderConfig.min_contribution` (OptiX's `optix::luminance`).
LUMINANCE = (0.30, 0.59, 0.11)


def _rgb(name: str, value) -> tuple[float, float, float]:
    rgb = np.asarray(value, np.float64)
    if rgb.shape != (3,) or not np.isfinite(rgb).all():
        raise ValueError(f"RenderConfig.{name} must be 3 finite numbers, got {value!r}")
    r, g, b = (float(c) for c in rgb)
    return r, g, b


@dataclasses.dataclass(frozen=True)
class RenderConfig:
    """How the integrator traces and shades. Hashable: every distinct config is compiled once.

    What the image is:

    - `max_depth`: reflection rays are spawned while depth < max_depth (primary rays have depth
      0), so at most `max_depth` bounces; 0 disables reflections. Thesis: 5.
    - `background`: radiance of rays that miss everything when no environment map is given
      (thesis: its "bg color").
    - `bad_color`: what a sample whose radiance is NaN or inf becomes (counted as bad; thesis:
      its exception colour).
    - `ray_offset`: secondary-ray origins move this far along the surface's geometric normal
      (to the side the new ray leaves from), relative to the scene's size (the larger of its
      bounding-box diagonal and its largest absolute coordinate), so surfaces never shadow or
      reflect themselves.
    - `hits`: where the distance t and barycentrics u, v of a hit come from. "recomputed"
      (the default): from the hit face's corners in `scene.vertices` (Möller–Trumbore), so the
      image follows vertices other than the BVH's build-time ones (differentiating a scene's
      geometry without rebuilding the BVH). "backend": the ray query's own t, u, v, for a
      scene whose vertices are the BVH's: equal up to float rounding, and cheaper
      (`benchmarks/mitsuba_frame.py --hits`). Derivatives are the same closed form at
      `scene.vertices` either way.
    - `specular`: the specular term of each light. "blinn-phong" (the default, and the thesis's
      implementation, §4.4.3: the halfway vector h = normalize(l − d), Ks·(n·h)^Ns) or "phong"
      (the thesis's eq. 1, §2.4: Ks·(r̂·v̂)^Ns with r̂ the light direction mirrored about the
      normal and v̂ = −d, counted where r̂·v̂ > 0).
    - `specular_payload`: multiply the specular term by n·l too. The thesis's closest-hit
      program (§4.4.3, Fig 61) sets the shadow ray's payload to n·l and multiplies both the
      diffuse and the specular contribution by "the payload of the shadow ray", so read
      literally its specular is Ks·(n·h)^Ns·(n·l)·light. Default False: fovjax's choice, the
      Blinn–Phong of OptiX's own samples (whose shadow payload is the attenuation 1), where
      n·l multiplies the diffuse term only. `fovjax.foveate.thesis_preset` sets it.
    - `min_contribution`: the contribution cut-off of §2.5.2 ("if the contribution of rays has
      a significant decrease there is no point to continue"): a reflection ray is spawned only
      where the luminance (0.30 R + 0.59 G + 0.11 B) of its weight, the product of the Kr of
      every surface on its path, is at least this. The thesis states the criterion but no
      threshold; its closest-hit program (`phong.cu`, Fig 51) comes from the OptiX SDK samples,
      whose `phong.h` spawns a reflection while that "importance" is >= 0.01, the value
      `fovjax.foveate.thesis_preset` takes (an inference from the SDK, not a line of the
      thesis; the SDK multiplies the luminance of each Kr, the same for grey mirrors). Default
      0: fovjax's choice, every reflection with a nonzero weight traced to `max_depth`.

    How it is computed (the image is the same up to float rounding whichever is chosen):

    - `backend`: the ray queries (`fovjax.trace.closest_hit`): "auto" (Embree through XLA's FFI
      on CPU where the native handlers build, Warp on CUDA where installed, else the JAX
      traversal; chosen per platform inside the program), "jax", "embree", "warp" or a
      registered `fovjax.trace.RayBackend`'s name. Only the hit face comes from the backend, so
      images differ at most by ties between faces at equal distance.
    - `integrator`: who runs the per-ray work (tracing, shading, shadow rays, reflections).
      "auto": on a CPU where the native handlers built and `backend` is "auto" or "embree", the
      native integrator (`fovjax/render/_whitted.cc`: the same arithmetic as the JAX integrator,
      written per ray); on an NVIDIA GPU where Warp is installed and `backend` is "auto" or
      "warp", the Warp integrator (`fovjax/render/_warp_whitted.py`: the same loop, one kernel
      launch per frame); elsewhere (another backend, shading classes of a per-region fidelity,
      image tiles of rays) the JAX integrator, chosen per platform inside the program.
      "native": the native integrator (a program for the CPU alone) or an error saying why not;
      "jax": always JAX.
      Derivatives are the JAX integrator's whichever ran the primal (a custom JVP); the two
      agree to float rounding except where a ray passes within rounding of an edge or a light's
      horizon (`tests/test_render_native.py` holds their agreement).
    - `packet`: traversal of primary rays and of the shadow rays from their hit points, as in
      `fovjax.trace.closest_hit` (a tile (h, w) over the last two batch axes of the rays, an int
      for runs of consecutive rays, or None for one by one; a tile needs rays with at least two
      batch axes laid out as an image). Reflection rays and later shadow rays are incoherent
      and always traced one by one.
    - `chunk_size`: the JAX integrator traces and shades depth 0 in bands of about this many
      rays (whole image rows, so that packets keep their pixels) and the reflection levels'
      live rays in chunks of the band's size (dead chunks are skipped).
    - `queue_chunk_size`: the chunk of the reflection levels of `radiance_in_chunks` (the
      foveated frame's JAX integrator), whose queues hold few rays.
    - `first_bounce_chunk_size`: the chunk of the first reflection level of
      `radiance_in_chunks`, whose queue holds every primary ray's mirror reflection (wider
      chunks trace it in fewer, fuller loops; `benchmarks/foveation.py` compares sizes); None:
      `queue_chunk_size` (one loop body for every level, a shorter compile).
    - `depth_batch_size`: `radiance_in_chunks` takes its slots through every depth level in
      batches of this many (rounded up to whole chunks), so the program's memory follows the
      batch and not the slot budget. None: one batch of every slot.
    """

    max_depth: int = 5
    background: tuple[float, float, float] = THESIS_BACKGROUND
    bad_color: tuple[float, float, float] = MAGENTA
    ray_offset: float = 1e-5
    packet: int | tuple[int, int] | None = (8, 8)
    backend: str = "auto"
    chunk_size: int = 32768
    queue_chunk_size: int = 4096
    first_bounce_chunk_size: int | None = 16384
    depth_batch_size: int | None = 262144
    hits: str = "recomputed"
    integrator: str = "auto"
    specular: str = "blinn-phong"
    specular_payload: bool = False
    min_contribution: float = 0.0

    def __post_init__(self):
        if not isinstance(self.max_depth, int | np.integer) or self.max_depth < 0:
            raise ValueError(f"RenderConfig.max_depth must be an integer >= 0, got {self.max_depth!r}")
        object.__setattr__(self, "max_depth", int(self.max_depth))
        object.__setattr__(self, "background", _rgb("background", self.background))
        object.__setattr__(self, "bad_color", _rgb("bad_color", self.bad_color))
        if not (np.isfinite(self.ray_offset) and self.ray_offset >= 0):
            raise ValueError(f"RenderConfig.ray_offset must be finite and >= 0, got {self.ray_offset!r}")
        object.__setattr__(self, "ray_offset", float(self.ray_offset))
        packet = self.packet
        if isinstance(packet, list):
            packet = tuple(packet)
        sizes = () if packet is None else (packet,) if isinstance(packet, int) else packet
        if packet is not None and (
            not isinstance(sizes, tuple)
            or len(sizes) not in (1, 2)
            or any(not isinstance(s, int) or s < 1 for s in sizes)
        ):
            raise ValueError(
                f"RenderConfig.packet must be None, a positive int or a (height, width) tile, got {packet!r}"
            )
        object.__setattr__(self, "packet", packet)
        if not isinstance(self.chunk_size, int | np.integer) or self.chunk_size < 1:
            raise ValueError(f"RenderConfig.chunk_size must be a positive integer, got {self.chunk_size!r}")
        object.__setattr__(self, "chunk_size", int(self.chunk_size))
        if not isinstance(self.queue_chunk_size, int | np.integer) or self.queue_chunk_size < 1:
            raise ValueError(
                f"RenderConfig.queue_chunk_size must be a positive integer, got {self.queue_chunk_size!r}"
            )
        object.__setattr__(self, "queue_chunk_size", int(self.queue_chunk_size))
        first = self.first_bounce_chunk_size
        if first is not None:
            if not isinstance(first, int | np.integer) or first < 1:
                raise ValueError(
                    f"RenderConfig.first_bounce_chunk_size must be None or a positive integer, got {first!r}"
                )
            object.__setattr__(self, "first_bounce_chunk_size", int(first))
        batch = self.depth_batch_size
        if batch is not None:
            if not isinstance(batch, int | np.integer) or batch < 1:
                raise ValueError(
                    f"RenderConfig.depth_batch_size must be None or a positive integer, got {batch!r}"
                )
            object.__setattr__(self, "depth_batch_size", int(batch))
        if self.hits not in HITS:
            raise ValueError(f"RenderConfig.hits must be one of {HITS}, got {self.hits!r}")
        if self.backend not in backend_names():
            raise ValueError(f"RenderConfig.backend must be one of {backend_names()}, got {self.backend!r}")
        if self.integrator not in INTEGRATORS:
            raise ValueError(f"RenderConfig.integrator must be one of {INTEGRATORS}, got {self.integrator!r}")
        if self.specular not in SPECULARS:
            raise ValueError(f"RenderConfig.specular must be one of {SPECULARS}, got {self.specular!r}")
        if not isinstance(self.specular_payload, bool | np.bool_):
            raise ValueError(
                f"RenderConfig.specular_payload must be True or False, got {self.specular_payload!r}"
            )
        object.__setattr__(self, "specular_payload", bool(self.specular_payload))
        cut = self.min_contribution
        if (
            isinstance(cut, bool)
            or not isinstance(cut, int | float | np.integer | np.floating)
            or not (np.isfinite(cut) and 0 <= cut <= 1)
        ):
            raise ValueError(f"RenderConfig.min_contribution must be a number in [0, 1], got {cut!r}")
        object.__setattr__(self, "min_contribution", float(cut))


DEFAULT_CONFIG = RenderConfig()
