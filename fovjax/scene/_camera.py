"""Pinhole cameras: where primary rays come from.

Camera frame: x right, y up, the camera looks along -z (OpenGL convention). Pixel (0, 0) is the
top-left pixel; row index grows downwards. The image plane spans the vertical field of view;
`offset` shifts the projection centre in units of the half-extent of the image plane (an
off-centre, "canted" projection: offset (0.1, 0) moves the centre of projection a tenth of the
half-width to the right).

Samples inside a pixel: `pixel_sample_positions(width, height, spp, key)` puts `spp` samples on a
sqrt(spp) x sqrt(spp) grid of equal cells in every pixel (at the cell centres, or jittered inside
each cell, independently per pixel, when a PRNG key is given); `Camera.sample_rays` turns them into
rays, and `Camera.project` maps world points back to continuous pixel coordinates.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float


def look_at_rotation(position, look_at, up=(0.0, 1.0, 0.0)) -> np.ndarray:
    """World-from-camera rotation (columns: right, up, backward) for a camera at `position`
    looking at `look_at`."""
    position = np.asarray(position, np.float64)
    forward = np.asarray(look_at, np.float64) - position
    norm = np.linalg.norm(forward)
    if not np.isfinite(norm) or norm == 0:
        raise ValueError(f"look_at_rotation: look_at {look_at} must differ from position {position}")
    forward /= norm
    right = np.cross(forward, np.asarray(up, np.float64))
    if np.linalg.norm(right) < 1e-9:
        raise ValueError(f"look_at_rotation: up {up} is parallel to the viewing direction")
    right /= np.linalg.norm(right)
    true_up = np.cross(right, forward)
    return np.stack([right, true_up, -forward], axis=1).astype(np.float32)


class Camera(eqx.Module):
    """A pinhole camera. `rotation` is world-from-camera (3x3); `vfov_deg` the vertical field
    of view; `offset` the projection-centre shift (see module docstring)."""

    position: Float[np.ndarray | Array, " 3"]
    rotation: Float[np.ndarray | Array, "3 3"]
    vfov_deg: Float[np.ndarray | np.number | Array, ""]
    offset: Float[np.ndarray | Array, " 2"]
    width: int = eqx.field(static=True)
    height: int = eqx.field(static=True)

    @classmethod
    def look_at(
        cls, position, look_at, up=(0.0, 1.0, 0.0), *, vfov_deg=60.0, width=640, height=480, offset=(0.0, 0.0)
    ):
        if width <= 0 or height <= 0:
            raise ValueError(f"Camera: resolution must be positive, got {width}x{height}")
        if not 0 < float(vfov_deg) < 180:
            raise ValueError(f"Camera: vfov_deg must be in (0, 180), got {vfov_deg}")
        pos = np.asarray(position, np.float32)
        if pos.shape != (3,) or not np.isfinite(pos).all():
            raise ValueError(f"Camera: position must be 3 finite numbers, got {position}")
        return cls(
            position=pos,
            rotation=look_at_rotation(position, look_at, up),
            vfov_deg=np.float32(vfov_deg),
            offset=np.asarray(offset, np.float32),
            width=int(width),
            height=int(height),
        )

    @classmethod
    def from_pose(cls, pose, *, width=640, height=480):
        """From a `fovjax.scenes.CameraPose`."""
        return cls.look_at(
            pose.position, pose.look_at, pose.up, vfov_deg=pose.vfov_deg, width=width, height=height
        )

    def ray_directions(self, pixel_xy: Float[np.ndarray | Array, "*batch 2"]) -> Float[Array, "*batch 3"]:
        """Unit world-space directions through continuous pixel coordinates (x right, y down;
        pixel (i, j) covers [i, i+1) x [j, j+1))."""
        return jnp.stack(self.ray_direction_components(pixel_xy[..., 0], pixel_xy[..., 1]), axis=-1)

    def ray_direction_components(self, x, y) -> tuple[Array, Array, Array]:
        """`ray_directions` as three arrays (x, y, z components; the same values) of continuous
        pixel coordinates `x` and `y`, which broadcast against each other (a row of columns and
        a column of rows give a screen): a caller that combines the components pixel by pixel
        gets one fused pass, no (..., 3) array."""
        sx, sy = self.image_plane(x, y)
        # Written out per component: XLA:CPU runs a matmul or a sum over a length-3 axis
        # through a far slower library kernel than this fused elementwise arithmetic.
        r = self.rotation
        d = [sx * r[i, 0] + sy * r[i, 1] - r[i, 2] for i in range(3)]
        scale = jax.lax.rsqrt(d[0] ** 2 + d[1] ** 2 + d[2] ** 2)
        return d[0] * scale, d[1] * scale, d[2] * scale

    def image_plane(self, x, y) -> tuple[Array, Array]:
        """Continuous pixel coordinates `x` and `y` (broadcasting against each other) on the
        camera's image plane at distance 1 (projection offset included): the ray through (x, y)
        is the rotation of (sx, sy, -1)."""
        tan_half = jnp.tan(jnp.deg2rad(self.vfov_deg) / 2)
        aspect = self.width / self.height
        sx = (2.0 * x / self.width - 1.0 + self.offset[0]) * tan_half * aspect
        sy = (1.0 - 2.0 * y / self.height + self.offset[1]) * tan_half
        return sx, sy

    def project(
        self, points: Float[Array, "*batch 3"]
    ) -> tuple[Float[Array, "*batch 2"], Float[Array, "*batch"]]:
        """Continuous pixel coordinates (x right, y down, as `ray_directions` takes them) of world
        points, and their depth along the viewing axis (negative: behind the camera)."""
        rel = jnp.asarray(points, jnp.float32) - self.position
        rot = jnp.asarray(self.rotation, jnp.float32)
        # The product with the rotation written out per component: XLA:CPU's dot of (N, 3) by
        # (3, 3) is several times slower than these multiply-adds over a screen of points.
        pc = rel[..., 0:1] * rot[0] + rel[..., 1:2] * rot[1] + rel[..., 2:3] * rot[2]
        depth = -pc[..., 2]
        tan_half = jnp.tan(jnp.deg2rad(self.vfov_deg) / 2)
        aspect = self.width / self.height
        sx = pc[..., 0] / depth
        sy = pc[..., 1] / depth
        x = 0.5 * self.width * (sx / (tan_half * aspect) - self.offset[0] + 1.0)
        y = 0.5 * self.height * (1.0 + self.offset[1] - sy / tan_half)
        return jnp.stack([x, y], axis=-1), depth

    def sample_rays(
        self, spp: int = 1, key: jax.Array | None = None
    ) -> tuple[Float[Array, "spp H W 3"], Float[Array, "spp H W 3"], Float[Array, "spp H W 2"]]:
        """`spp` rays per pixel on the stratified grid of `pixel_sample_positions` (jittered when
        `key` is given): (origins, unit directions, pixel coordinates), sample axis first."""
        xy = pixel_sample_positions(self.width, self.height, spp, key)
        d = self.ray_directions(xy)
        return jnp.broadcast_to(self.position, d.shape), d, xy

    def pixel_centres(self) -> Float[Array, "H W 2"]:
        x = jnp.arange(self.width, dtype=jnp.float32) + 0.5
        y = jnp.arange(self.height, dtype=jnp.float32) + 0.5
        xx, yy = jnp.meshgrid(x, y)
        return jnp.stack([xx, yy], axis=-1)

    def primary_rays(self) -> tuple[Float[Array, "H W 3"], Float[Array, "H W 3"]]:
        """One ray through each pixel centre: (origins, directions), each (H, W, 3)."""
        d = self.ray_directions(self.pixel_centres())
        o = jnp.broadcast_to(self.position, d.shape)
        return o, d


def stratified_offsets(spp: int, key: jax.Array | None = None) -> Float[Array, "spp 2"]:
    """Sub-pixel sample positions in [0, 1)^2 on a sqrt(spp) x sqrt(spp) grid, at cell centres,
    or jittered uniformly inside each cell when `key` is given."""
    n = int(round(spp**0.5))
    if n * n != spp or spp < 1:
        raise ValueError(f"spp must be a positive square (1, 4, 9, 16, ...), got {spp}")
    i = jnp.arange(n, dtype=jnp.float32)
    gx, gy = jnp.meshgrid(i, i)
    cells = jnp.stack([gx.reshape(-1), gy.reshape(-1)], -1)
    jitter = 0.5 if key is None else jax.random.uniform(key, (spp, 2), jnp.float32)
    return (cells + jitter) / n


def vfov_from_hfov(hfov_deg, width: int, height: int):
    """The vertical field of view (degrees) of a `width` x `height` pinhole image whose
    horizontal field of view is `hfov_deg` (square pixels). Works on arrays and tracers."""
    half = jnp.tan(jnp.deg2rad(jnp.asarray(hfov_deg, jnp.float32)) / 2)
    return jnp.rad2deg(2 * jnp.arctan(half * (height / width)))


def pixel_sample_positions(
    width: int, height: int, spp: int = 1, key: jax.Array | None = None
) -> Float[Array, "spp H W 2"]:
    """Continuous pixel coordinates of `spp` samples in every pixel of a width x height image.

    Sample s lies in cell (s % n, s // n) of an n x n grid over the pixel (n = sqrt(spp)): at the
    cell's centre without a key, uniformly inside the cell with one (independent draws for every
    pixel and sample). With spp = 1 and no key that is the pixel centre.
    """
    grid = stratified_offsets(spp)  # (spp, 2) cell centres
    n = int(round(spp**0.5))
    x = jnp.arange(width, dtype=jnp.float32)
    y = jnp.arange(height, dtype=jnp.float32)
    xx, yy = jnp.meshgrid(x, y)
    corner = jnp.stack([xx, yy], axis=-1)  # (H, W, 2) top-left corner of each pixel
    if key is None:
        offsets = grid[:, None, None, :]
    else:
        jitter = jax.random.uniform(key, (spp, height, width, 2), jnp.float32)
        offsets = grid[:, None, None, :] + (jitter - 0.5) / n
    return corner[None] + offsets


def per_sample_threefry(key) -> bool:
    """Whether `jax.random.uniform(key, shape)` draws element i as threefry2x32 of the key and the
    64-bit counter i, which the native handlers and `fovjax.foveate`'s `uniform_at` reproduce
    per sample: JAX's default PRNG with `jax_threefry_partitionable` (the default since JAX
    0.5), a typed threefry2x32 key or a raw (2,) uint32 one."""
    # jax.config's options are set at run time (pyright cannot see it).
    if not jax.config.jax_threefry_partitionable:  # pyright: ignore[reportAttributeAccessIssue]
        return False
    if jnp.issubdtype(key.dtype, jax.dtypes.prng_key):
        return str(jax.random.key_impl(key)) == "threefry2x32"
    raw = key.shape == (2,) and key.dtype == jnp.uint32
    # jax.config's options are set at run time (pyright cannot see it).
    impl = jax.config.jax_default_prng_impl  # pyright: ignore[reportAttributeAccessIssue]
    return raw and impl == "threefry2x32"


def key_words(key) -> Array:
    """A PRNG key's uint32 words: `jax.random.key_data` of a typed key, a raw key as it is."""
    data = jax.random.key_data(key) if jnp.issubdtype(key.dtype, jax.dtypes.prng_key) else key
    return jnp.asarray(data, jnp.uint32)
