"""How much memory a frame needs, checked against the machine's before any work.

A frame program's buffers grow with its samples (pixels x SPP) and pixels; XLA allocates them
all at once when the program runs, so a frame too large for the machine is not slow, it is
killed by the kernel (or, on a GPU, fails inside XLA) after the BVH and the compile. The
estimate below is read from what the programs allocate (`_frame._stereo_program`,
`fovjax.foveate`'s `foveated_stereo`), per sample, per pixel and per band of rays, rounded up;
`tests/test_memory.py` checks it is at least what XLA assigns to the compiled programs.

Bytes per sample of a full frame (`_stereo_program`): the sample rays' origins and directions
(24), the integrator's radiance and ray counts (16), the sub-pixel positions (8 per sample, shared
by both eyes: 4), the active, valid and bad flags (3): 48 in all with the native integrator,
which keeps each ray's intermediates to itself. (The camera frame handler, `render/_frame.cc`,
makes the rays block by block and needs none of these; 48 stays the bound of the frames it does
not take, a key of another PRNG's.) The JAX integrator adds its two reflection
queues (origin, direction, weight and pixel of every sample that may reflect: 40 each), 128 in
all, and the intermediates of one band of depth 0 (`RenderConfig.chunk_size` rays, every shading
stage materialised: about 400 per ray). Per pixel: the resolved eyes and the side-by-side image
(24). A foveated frame (thesis section 4) never makes screen-sized ray arrays: per sample only
the selection and its compaction order (8; 24 with the JAX integrator, whose slots also carry
their radiance), per pixel the image, the pre-fill mean, the fill and blur passes and the
diagnostics (64), and with the JAX integrator the reflection queues of one depth batch
(`RenderConfig.depth_batch_size`). Both: the image on the host and what writing it makes (48
per pixel).
"""

from __future__ import annotations

import os
from pathlib import Path

from ._config import DEFAULT_CONFIG, RenderConfig

# Bytes per sample, per pixel, per ray of a band, per queued ray (see the module docstring).
FULL_PER_SAMPLE = {"native": 48, "jax": 128}
FULL_PER_PIXEL = 24
FOVEATED_PER_SAMPLE = {"native": 8, "jax": 24}
FOVEATED_PER_PIXEL = 64
BAND_PER_RAY = 400
QUEUE_PER_RAY = 80
HOST_PER_PIXEL = 48
# Linear float32 RGB of one kept image (a sequence held for a video metric or clips).
KEPT_PER_PIXEL = 12

SIZE_CHECK_VARIABLE = "FOVJAX_SIZE_CHECK"


class FrameTooLargeError(ValueError):
    """A frame whose estimated memory (`frame_memory`) exceeds what the machine has free
    (`memory_limit`): refused before the BVH or a compile. `FOVJAX_SIZE_CHECK=0` (the command
    line's `--no-size-check`) turns the check off."""


def _integrator(config: RenderConfig, platform: str) -> str:
    """The integrator a frame of `config` runs on `platform`: "native" or "jax"."""
    if platform != "cpu" or config.integrator == "jax":
        return "jax"
    from ..native import building
    from ._integrator import native_integrator
    from ._native import native_why_not

    if building():
        # The handlers still compile in the background (a machine's first run): the estimate
        # for the integrator they will run, without waiting; a frame checks again when it is
        # made, once they are loaded.
        return "jax" if native_why_not(config) else "native"

    try:
        return "native" if native_integrator(config) else "jax"
    except (ValueError, RuntimeError):  # said when the frame is made; the larger estimate here
        return "jax"


def frame_memory(
    eye_width: int,
    eye_height: int,
    spp: int = 1,
    *,
    foveated: bool = False,
    eyes: int = 2,
    config: RenderConfig | None = None,
    integrator: str | None = None,
    kept_images: int = 0,
) -> int:
    """An upper estimate of the memory, in bytes, one frame takes while it renders: the
    compiled program's buffers and the image on the host (see the module docstring).

    Args:
        eye_width: pixels per eye, horizontally (a mono frame: its width).
        eye_height: pixels per eye, vertically.
        spp: samples per pixel.
        foveated: a foveated frame (`fovjax.foveate`) rather than a full one.
        eyes: 2 for a stereo frame, 1 for a mono one.
        config: the `RenderConfig` (default `RenderConfig()`): which integrator runs and its
            band and depth-batch sizes.
        integrator: "native" or "jax" to estimate for that integrator; None: the one `config`
            runs on JAX's default platform.
        kept_images: frames of this size held in memory besides (a sequence for a video metric).

    Returns:
        The estimate in bytes.
    """
    config = DEFAULT_CONFIG if config is None else config
    if integrator is None:
        import jax

        integrator = _integrator(config, jax.default_backend())
    if integrator not in FULL_PER_SAMPLE:
        raise ValueError(f"frame_memory: integrator must be 'native' or 'jax', got {integrator!r}")
    pixels = int(eyes) * int(eye_width) * int(eye_height)
    samples = pixels * int(spp)
    if foveated:
        total = FOVEATED_PER_SAMPLE[integrator] * samples + FOVEATED_PER_PIXEL * pixels
        if integrator == "jax":
            batch = config.depth_batch_size or samples
            total += QUEUE_PER_RAY * min(samples, batch) + BAND_PER_RAY * min(samples, config.chunk_size)
    else:
        total = FULL_PER_SAMPLE[integrator] * samples + FULL_PER_PIXEL * pixels
        if integrator == "jax":
            total += BAND_PER_RAY * min(samples, config.chunk_size)
    return total + HOST_PER_PIXEL * pixels + KEPT_PER_PIXEL * pixels * int(kept_images)


def _meminfo_available() -> int | None:
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


def _cgroup_free() -> int | None:
    """Room left under this process's cgroup (v2) memory limit, where it has one."""
    try:
        line = Path("/proc/self/cgroup").read_text().splitlines()[0]
        group = Path("/sys/fs/cgroup") / line.split("::", 1)[1].lstrip("/")
        limit = (group / "memory.max").read_text().strip()
        if limit == "max":
            return None
        return int(limit) - int((group / "memory.current").read_text().strip())
    except (OSError, ValueError, IndexError):
        return None


def memory_limit(platform: str | None = None) -> tuple[int | None, str]:
    """The memory a frame may take on `platform` (default JAX's default backend), in bytes, and
    what that number is: on a CPU the machine's available memory (`MemAvailable` of
    /proc/meminfo, or `os.sysconf`'s free pages where there is none; less where the process's
    cgroup allows less); on a GPU the device's free memory. None where nothing says."""
    if platform is None:
        import jax

        platform = jax.default_backend()
    if platform != "cpu":
        import jax

        device = jax.devices()[0]
        stats = device.memory_stats() or {}
        if "bytes_limit" in stats:
            free = int(stats["bytes_limit"]) - int(stats.get("bytes_in_use", 0))
            return free, f"free on the {device.device_kind}"
    available = _meminfo_available()
    what = "available on this machine"
    if available is None:
        try:
            available = os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
        except (ValueError, OSError, AttributeError):
            return None, what
    cgroup = _cgroup_free()
    if cgroup is not None and cgroup < available:
        return cgroup, "free under this process's memory limit (cgroup)"
    return available, what


def size_check_enabled() -> bool:
    """False where `FOVJAX_SIZE_CHECK=0`: frames are not checked against the machine's memory."""
    from .. import _environment

    return _environment.switch(SIZE_CHECK_VARIABLE)


def _bytes(n: int) -> str:
    if n >= 1e12:
        return f"{n / 1e12:.1f} TB"
    return f"{n / 1e9:.1f} GB" if n >= 1e8 else f"{n / 1e6:.0f} MB"


def check_frame_memory(
    eye_width: int,
    eye_height: int,
    spp: int = 1,
    *,
    foveated: bool = False,
    eyes: int = 2,
    config: RenderConfig | None = None,
    integrator: str | None = None,
    kept_images: int = 0,
    where: str = "render",
) -> int:
    """Refuse a frame whose `frame_memory` exceeds `memory_limit`, naming the size, the
    estimate and the limit; nothing is checked where `FOVJAX_SIZE_CHECK=0` or the limit is not
    known. Arguments as `frame_memory`; `where` begins the message.

    Returns:
        The estimate in bytes.

    Raises:
        FrameTooLargeError: the estimate exceeds the limit.
    """
    estimate = frame_memory(
        eye_width,
        eye_height,
        spp,
        foveated=foveated,
        eyes=eyes,
        config=config,
        integrator=integrator,
        kept_images=kept_images,
    )
    if not size_check_enabled():
        return estimate
    limit, what = memory_limit()
    if limit is not None and estimate > limit:
        size = f"{eyes} x {eye_width}x{eye_height}" if eyes != 1 else f"{eye_width}x{eye_height}"
        kind = "foveated" if foveated else "full"
        raise FrameTooLargeError(
            f"{where}: a {kind} frame of {size} pixels at SPP {spp} needs about {_bytes(estimate)}, more "
            f"than the {_bytes(max(limit, 0))} {what}; make it smaller, or set {SIZE_CHECK_VARIABLE}=0 "
            "(--no-size-check) on a machine that has the memory"
        )
    return estimate
