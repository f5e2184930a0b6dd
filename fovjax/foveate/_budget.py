"""The static ray budget of a foveated frame: how many sample slots are traced per eye."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from ._config import max_region_spp
from ._eccentricity import eccentricity_map
from ._sampling import FOVEA, allowed_samples, regions, thesis_measured_mandatory, top_left

BUDGET_SIGMAS = 6.0
BUDGET_GRID = 7  # gaze positions per axis examined (corners, edges and centre included)
PACKET = 64


def _gaze_counts(camera, gaze, foveation):
    """Per frame (all sub-samples): (mandatory samples, expected and variance of probabilistic
    ones). The rules other than "thesis-measured" treat every sub-sample layer alike."""
    ecc = eccentricity_map(camera, gaze, foveation)
    region = regions(ecc, foveation)
    ty, tx, _ = top_left(region, foveation)
    is_tl = jnp.zeros(region.shape, bool).at[ty, tx].set(True)
    p = foveation.probability(ecc)
    fovea = region == FOVEA
    spp = foveation.spp
    allowed = allowed_samples(region, foveation)  # None, or (spp, H, W)
    if foveation.rule == "thesis-measured":
        wanted = thesis_measured_mandatory(region, spp)
        wanted = wanted if allowed is None else wanted & allowed
        m = jnp.sum(wanted).astype(jnp.float32)
        return jnp.stack([m, jnp.float32(0), jnp.float32(0)])
    if foveation.rule == "either":
        mandatory = fovea | is_tl
        chance = jnp.where(mandatory, 0.0, p)
    else:
        mandatory = fovea
        chance = jnp.where(~fovea & is_tl, p, 0.0)
    if allowed is not None:  # each pixel's own number of sub-samples
        k = jnp.sum(allowed, axis=0).astype(jnp.float32)
        counts = [jnp.sum(mandatory * k), jnp.sum(chance * k), jnp.sum(chance * (1 - chance) * k)]
        return jnp.stack(counts).astype(jnp.float32)
    counts = jnp.stack([jnp.sum(mandatory), jnp.sum(chance), jnp.sum(chance * (1 - chance))])
    return spp * counts.astype(jnp.float32)


# One program per camera size and foveation structure, kept across renderers (a new jit per call
# compiled it again for every renderer).
_grid_counts = jax.jit(jax.vmap(_gaze_counts, in_axes=(None, 0, None)))


def plan_budget(camera, foveation) -> int:
    """Sample slots per eye so that the traced samples fit for any gaze on the screen.

    For gaze positions on a 7×7 grid over the display (corners included) it counts the samples
    that must be traced (fovea; block top-lefts under the "either" rule; all of them under
    "thesis-measured", which draws nothing) and the expected number
    of probabilistic ones with their variance, and keeps the worst case of
    mandatory + expected + 6σ, plus 2% and one packet of headroom for gaze between grid points;
    rounded up to whole 64-ray packets, at most the full sample count. Frames that still exceed
    it drop their last probabilistic samples and count them (`Frame.stats`)."""
    if foveation.ray_budget is not None:
        return int(foveation.ray_budget)
    full = max_region_spp(foveation) * camera.height * camera.width
    grid = np.linspace(0.0, 1.0, BUDGET_GRID, dtype=np.float32)
    gazes = np.stack(np.meshgrid(grid, grid), -1).reshape(-1, 2)
    stats = np.asarray(_grid_counts(camera, gazes, foveation))
    m, mean, var = (stats[:, i] for i in range(3))
    worst = float(np.max(m + mean + BUDGET_SIGMAS * np.sqrt(var)))
    budget = int(np.ceil(worst * 1.02)) + PACKET
    budget = -(-budget // PACKET) * PACKET
    return int(min(budget, full))
