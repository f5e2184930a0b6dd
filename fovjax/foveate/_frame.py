"""The foveated stereo frame: select samples, compact them, trace only those, fill and blur.

Data flow inside one jitted program (static shapes throughout):

1. the frame's sub-sample positions (spp × H × W per eye), exactly as a full render makes them
   (the same key gives the same sub-pixel positions);
2. each eye's eccentricity map from its gaze point, regions, and the sample classes
   (mandatory / probabilistic / skipped) drawn from a stream of the frame key;
3. compaction: a stable O(N) partition puts traced samples first; the first `budget` slots (a
   static number fixed per configuration by `plan_budget`) become a dense batch of rays,
   computed from the slots' indices;
4. the Whitted integrator runs on that batch only — primary rays, then shadow and reflection
   rays spawned by them — so the cost follows the traced samples, not the screen;
5. results are accumulated into their pixels, and each eye is filled and blurred in one pass
   (`fill_and_blur_pixels`).

Ray counts are rays actually traced; the padding (budget slots left empty) and any samples
dropped beyond the budget are reported separately.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from ._eccentricity import eccentricity_map
from ._fill import fill_and_blur_pixels
from ._sampling import MANDATORY, OPTIONAL, compaction_order, sample_classes

# fold_in constant that separates the sampling draws from the sub-pixel jitter of the same key.
SAMPLING_STREAM = 0x5A3


class FoveatedOutputs(NamedTuple):
    image: Float[Array, "H W2 3"]
    counts: object  # fovjax.render RayCounts
    primary_by_region: Int[Array, " 3"]
    mandatory: Int[Array, ""]
    optional: Int[Array, ""]
    dropped: Int[Array, ""]
    padding: Int[Array, ""]
    traced: Bool[Array, "2 S H W"]
    region: Int[Array, "2 H W"]
    eccentricity: Float[Array, "2 H W"]
    prefill: Float[Array, "2 H W 3"]


class Selection(NamedTuple):
    """Which samples of a stereo frame are traced: per-eye eccentricity and regions, the class
    of every sample (2, S, H, W), the count per class, and the `budget` slots (flat sample
    indices into (2, S, H, W)) with which of them hold a wanted sample."""

    eccentricity: Float[Array, "2 H W"]
    region: Int[Array, "2 H W"]
    classes: Int[Array, "2 S H W"]
    counts: Int[Array, " 3"]
    slots: Int[Array, " B"]
    active: Bool[Array, " B"]


def eccentricities(cameras, gaze, foveation) -> Float[Array, "2 H W"]:
    """Stage 1: each eye's eccentricity map from its gaze point."""
    return jnp.stack([eccentricity_map(cam, gaze[i], foveation) for i, cam in enumerate(cameras)])


def select_samples(ecc, key, *, foveation, budget) -> Selection:
    """Stage 2: regions, sample classes from the sampling stream of `key`, and the compaction
    of the traced samples into `budget` slots."""
    keys = jax.random.split(jax.random.fold_in(key, SAMPLING_STREAM), 2)
    classes, region = zip(*(sample_classes(ecc[i], foveation, keys[i]) for i in range(2)), strict=True)
    classes, region = jnp.stack(classes), jnp.stack(region)  # (2, S, H, W), (2, H, W)
    order, counts = compaction_order(classes.reshape(-1))
    wanted = counts[MANDATORY] + counts[OPTIONAL]
    slots = order[:budget]
    active = jnp.arange(budget) < wanted
    return Selection(ecc, region, classes, counts, slots, active)


def slot_rays(cameras, slots, key, *, spp, jitter, h, w):
    """Primary rays of the slots: the full render's sub-pixel positions (the same key gives the
    same positions), directions computed from the indices (no screen-sized ray arrays)."""
    from .._camera import pixel_sample_positions

    per_eye = spp * h * w
    eye = slots // per_eye
    in_eye = slots % per_eye  # index into (S, H, W)
    xy = pixel_sample_positions(w, h, spp, key if jitter else None).reshape(-1, 2)[in_eye]
    left, right = cameras
    is_left = (eye == 0)[:, None]
    directions = jnp.where(is_left, left.ray_directions(xy), right.ray_directions(xy))
    origins = jnp.where(is_left, left.position, right.position)
    return origins, directions


def reconstruct(rgb, selection: Selection, *, spp, h, w, foveation):
    """Last stage: accumulate the traced samples into their pixels, fill and blur each eye.
    Returns (side-by-side image, per-pixel traced counts (2, H, W), prefill (2, H, W, 3),
    traced sample mask (2, S, H, W), primary rays per region (3,))."""
    slots, active, region, ecc = selection.slots, selection.active, selection.region, selection.eccentricity
    per_eye = spp * h * w
    pixel = (slots // per_eye) * (h * w) + (slots % per_eye) % (h * w)
    rgb = jnp.where(active[:, None], rgb, 0.0)
    sums = jnp.zeros((2 * h * w, 3), jnp.float32).at[pixel].add(rgb).reshape(2, h, w, 3)
    n_traced = jnp.zeros(2 * h * w, jnp.int32).at[pixel].add(active.astype(jnp.int32)).reshape(2, h, w)
    prefill = sums / jnp.maximum(n_traced, 1)[..., None]
    eyes = [fill_and_blur_pixels(prefill[i], n_traced[i], region[i], ecc[i], foveation)[0] for i in range(2)]
    image = jnp.concatenate(eyes, axis=1)
    traced = jnp.zeros(selection.classes.size, bool).at[slots].set(active).reshape(selection.classes.shape)
    # One scatter-add instead of three masked reductions (slow on XLA:CPU).
    by_region = jnp.zeros(3, jnp.int32).at[region.reshape(-1)].add(n_traced.reshape(-1))
    return image, n_traced, prefill, traced, by_region


def foveated_stereo(scene, bvh, rig, head_pose, gaze, key, *, spp, jitter, config, foveation, budget):
    """One foveated stereo frame (see the module docstring). Pure; jit with the keyword
    arguments static. `gaze` (2, 2): per-eye normalised display coordinates.

    Only the `budget` selected samples ever become rays: their sub-pixel positions are the full
    render's (`pixel_sample_positions` from the same key) and their directions are computed
    from their indices, so no screen-sized ray arrays exist."""
    from ..render._integrator import radiance

    cameras = rig.eye_cameras(head_pose)
    h, w = rig.eye_height, rig.eye_width
    ecc = eccentricities(cameras, gaze, foveation)
    sel = select_samples(ecc, key, foveation=foveation, budget=budget)
    origins, directions = slot_rays(cameras, sel.slots, key, spp=spp, jitter=jitter, h=h, w=w)
    result = radiance(scene, bvh, origins, directions, sel.active, config=config)
    image, _, prefill, traced, by_region = reconstruct(
        result.rgb, sel, spp=spp, h=h, w=w, foveation=foveation
    )
    counts = sel.counts
    wanted = counts[MANDATORY] + counts[OPTIONAL]
    return FoveatedOutputs(
        image=image,
        counts=result.counts,
        primary_by_region=by_region.astype(jnp.int32),
        mandatory=counts[MANDATORY],
        optional=counts[OPTIONAL],
        dropped=jnp.maximum(wanted - budget, 0),
        padding=jnp.maximum(budget - wanted, 0),
        traced=traced,
        region=sel.region,
        eccentricity=ecc,
        prefill=prefill,
    )


@dataclasses.dataclass(frozen=True)
class FoveationStats:
    """Per-frame foveation figures: primary rays traced per region (fovea, periphery,
    outside), the samples the plan asked for (mandatory + probabilistic), the static budget,
    the budget slots left empty (padding) and samples dropped because the budget was full."""

    primary_by_region: tuple[int, int, int]
    mandatory: int
    optional: int
    budget: int
    padding: int
    dropped: int
    fovea_deg: float
    periphery_deg: float


def region_view(outputs: FoveatedOutputs, *, dim: float = 0.12) -> Float[Array, "H W2 3"]:
    """The debug view of thesis figures 58–59: each eye right after ray generation — pixels with
    a traced sample in their rendered colour, the others in a dim colour of their region
    (periphery yellow, outside red) — and the fovea's edge drawn green."""
    colours = jnp.array([[0.0, 0.0, 0.0], [1.0, 0.8, 0.1], [1.0, 0.15, 0.1]], jnp.float32)
    traced = jnp.any(outputs.traced, axis=1)[..., None]
    shown = jnp.where(traced, outputs.prefill, dim * colours[outputs.region])
    # One-pixel ring where the region changes from fovea to periphery.
    fovea = outputs.region == 0
    edge = fovea & ~(
        jnp.roll(fovea, 1, 1) & jnp.roll(fovea, -1, 1) & jnp.roll(fovea, 1, 2) & jnp.roll(fovea, -1, 2)
    )
    shown = jnp.where(edge[..., None], jnp.array([0.1, 1.0, 0.1]), shown)
    return jnp.concatenate([shown[0], shown[1]], axis=1)
