"""The frame as a function of the parameters a user chooses: `differentiable`, `Parameters`.

`differentiable(render_fn, scene, names, ...)` picks scene values by name (material colours of
some or all materials, lights, vertices, the camera's position, the head pose) and returns a
`Differentiable`: called with a `Parameters` pytree holding only those values, it puts them back
into the scene arrays (and the view, and the head pose) and calls `render_fn`. `jax.grad`,
`jax.value_and_grad` and `jax.jvp` of a loss of it then carry only the chosen values: the
scene arrays not chosen (the vertices and normals, when only colours are) are constants to them,
and no gradient is computed for them. `render_fn` is any function of the
scene arrays (the full stereo frame, one camera's image, a frame built on them), so a frame
that becomes differentiable is used the same way.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..scene import Camera, Scene
from ._arrays import SceneArrays, scene_arrays
from ._stereo import HeadPoseLike, StereoRig, head_pose_angles

# What each name selects. Materials' rows can be narrowed (`materials=`), lights' (`lights=`)
# and vertices' (`vertices=`); the rest are taken whole.
MATERIAL_NAMES = ("ka", "kd", "ks", "ke", "kr", "ns")
LIGHT_NAMES = ("light_position", "light_color")
VERTEX_NAMES = ("vertices",)
WHOLE_SCENE_NAMES = ("ambient", "environment")
VIEW_NAMES = ("camera_position",)
POSE_NAMES = ("head_pose",)
PARAMETER_NAMES: tuple[str, ...] = (
    MATERIAL_NAMES + LIGHT_NAMES + VERTEX_NAMES + WHOLE_SCENE_NAMES + VIEW_NAMES + POSE_NAMES
)
"""Every name `differentiable` takes: the materials' `ka`, `kd`, `ks`, `ke`, `kr`, `ns`, the
lights' `light_position` and `light_color`, `vertices`, `ambient`, `environment`, the view's
`camera_position` and the `head_pose`."""
_SCENE_NAMES = MATERIAL_NAMES + LIGHT_NAMES + VERTEX_NAMES + WHOLE_SCENE_NAMES


def _float32_values(values: dict) -> dict:
    if not isinstance(values, dict):
        raise TypeError(f"Parameters: values must be a dict of name -> array, got {type(values).__name__}")
    return {name: jnp.asarray(value, jnp.float32) for name, value in values.items()}


class Parameters(eqx.Module):
    """The values of the chosen parameters, by name: a pytree whose leaves are exactly those
    values, so `jax.grad` of a function of it returns a `Parameters` of the same names and
    shapes, and `jax.tree.map` combines several (an optimiser's update, a tangent for
    `jax.jvp`).

    Read a value as `params["kd"]`; make new ones with `Parameters({"kd": ..., ...})` (the
    `Differentiable` that reads them checks the names and shapes) or from others with
    `jax.tree.map`.

    Attributes:
        values: name → array, each made a float32 JAX array (not weakly typed: a Python
            number's array and the values a step computes from it then compile as one program).
    """

    values: dict[str, Float[Array, "..."]] = eqx.field(converter=_float32_values)

    def __getitem__(self, name: str) -> Float[Array, "..."]:
        if name not in self.values:
            raise KeyError(f"Parameters: no parameter {name!r}; these are {', '.join(self.values)}")
        return self.values[name]

    @property
    def names(self) -> tuple[str, ...]:
        """The parameters' names (JAX's transformations return them in sorted order)."""
        return tuple(self.values)


RowsLike = Sequence[int | str] | None


class Differentiable(eqx.Module):
    """A render function as a function of the parameters chosen by `differentiable`: call it
    with a `Parameters` (`frame(params, *args, **kwargs)`) for `render_fn`'s output with those
    values in the scene. Make it with `differentiable`; make it once and reuse it, so that a
    `jax.jit` of a loss of it compiles once. It is hashed and compared by identity, so
    `jax.jit(frame)` works as for a function; it is also a pytree (of the scene arrays and the
    view), so `eqx.filter_jit` can take it as an argument, tracing its arrays rather than
    compiling them in as constants.

    Attributes:
        render_fn: the function rendered, called as `render_fn(arrays, *args, view=...,
            head_pose=..., **kwargs)` (`view` and `head_pose` only where `differentiable` was
            given them).
        arrays: the scene arrays the parameters are put into.
        view: the `Camera` or `StereoRig` handed to `render_fn` as `view=`, or None.
        head_pose: the (yaw, pitch, roll) in degrees handed to `render_fn` as `head_pose=`, or
            None.
        names: the chosen parameters' names.
        material_rows: the material rows the material parameters hold (None: all).
        light_rows: the light rows the light parameters hold (None: all).
        vertex_rows: the vertex rows `vertices` holds (None: all).
    """

    render_fn: Callable[..., Any]
    arrays: SceneArrays
    view: Camera | StereoRig | None
    head_pose: Float[np.ndarray | Array, " 3"] | None
    names: tuple[str, ...]
    material_rows: tuple[int, ...] | None
    light_rows: tuple[int, ...] | None
    vertex_rows: tuple[int, ...] | None

    # By identity: a function to `jax.jit` (which hashes what it compiles); the fields hold
    # arrays, which have no hash.
    __hash__ = object.__hash__

    def __eq__(self, other: object) -> bool:
        return self is other

    @property
    def parameters(self) -> Parameters:
        """The chosen parameters' values in the scene this was made from: a starting point, or
        the truth to compare with."""
        return Parameters({name: jnp.asarray(self._value(name), jnp.float32) for name in self.names})

    def _value(self, name: str):
        if name == "camera_position":
            assert self.view is not None  # differentiable() checked
            return self.view.position
        if name == "head_pose":
            return self.head_pose
        leaf = getattr(self.arrays, name)
        rows = self._rows(name)
        return leaf if rows is None else jnp.asarray(leaf)[np.asarray(rows)]

    def _shape(self, name: str) -> tuple[int, ...]:
        if name in _SCENE_NAMES:
            shape = tuple(np.shape(getattr(self.arrays, name)))
            rows = self._rows(name)
            return shape if rows is None else (len(rows),) + shape[1:]
        return (3,)  # camera_position, head_pose

    def _rows(self, name: str) -> tuple[int, ...] | None:
        if name in MATERIAL_NAMES:
            return self.material_rows
        if name in LIGHT_NAMES:
            return self.light_rows
        if name in VERTEX_NAMES:
            return self.vertex_rows
        return None

    def inputs(
        self, params: Parameters
    ) -> tuple[SceneArrays, Camera | StereoRig | None, Float[np.ndarray | Array, " 3"] | None]:
        """(scene arrays, view, head pose) with `params` put in their places: what `render_fn`
        is called with. Raises a TypeError for what is not a `Parameters`, a ValueError for
        other names or shapes than this frame's."""
        self._check(params)
        values = {name: jnp.asarray(params.values[name], jnp.float32) for name in self.names}
        scene_names = [name for name in self.names if name in _SCENE_NAMES]
        arrays = self.arrays
        if scene_names:
            placed = []
            for name in scene_names:
                rows = self._rows(name)
                if rows is None:
                    placed.append(values[name])
                else:
                    whole = jnp.asarray(getattr(self.arrays, name), jnp.float32)
                    placed.append(whole.at[np.asarray(rows)].set(values[name]))
            arrays = eqx.tree_at(
                lambda a: tuple(getattr(a, name) for name in scene_names), self.arrays, tuple(placed)
            )
        view = self.view
        if "camera_position" in values:
            view = eqx.tree_at(lambda v: v.position, self.view, values["camera_position"])
        head_pose = values.get("head_pose", self.head_pose)
        return arrays, view, head_pose

    def _check(self, params) -> None:
        if not isinstance(params, Parameters):
            raise TypeError(
                f"Differentiable: expected a Parameters (this frame's: {', '.join(self.names)}), "
                f"got {type(params).__name__}"
            )
        given = tuple(params.values)
        if set(given) != set(self.names):
            missing = [n for n in self.names if n not in given]
            extra = [n for n in given if n not in self.names]
            raise ValueError(
                f"Differentiable: the parameters are {', '.join(self.names)}; "
                f"got {', '.join(given) or 'none'}"
                + (f" (missing {', '.join(missing)})" if missing else "")
                + (f" (not chosen: {', '.join(extra)})" if extra else "")
            )
        for name in self.names:
            expected, got = self._shape(name), np.shape(params.values[name])
            if tuple(got) != tuple(expected):
                raise ValueError(f"Differentiable: parameter {name!r} must have shape {expected}, got {got}")

    def __call__(self, params: Parameters, *args: Any, **kwargs: Any) -> Any:
        """`render_fn`'s output with `params` in the scene: `render_fn(arrays, *args, view=,
        head_pose=, **kwargs)`, the view and head pose passed only where `differentiable` was
        given them."""
        arrays, view, head_pose = self.inputs(params)
        if self.view is not None:
            kwargs = {**kwargs, "view": view}
        if self.head_pose is not None:
            kwargs = {**kwargs, "head_pose": head_pose}
        return self.render_fn(arrays, *args, **kwargs)


def differentiable(
    render_fn: Callable[..., Any],
    scene: Scene | SceneArrays,
    names: str | Sequence[str],
    *,
    view: Camera | StereoRig | None = None,
    head_pose: HeadPoseLike = None,
    materials: RowsLike = None,
    lights: Sequence[int] | None = None,
    vertices: Sequence[int] | None = None,
) -> Differentiable:
    """`render_fn` as a function of the scene values named in `names`, and nothing else.

    The returned `Differentiable` is called with a `Parameters` holding only those values
    (`frame.parameters` gives the scene's own); it puts them back into the scene arrays (with
    `eqx.tree_at`), the view and the head pose, and calls `render_fn`. A gradient of a loss of
    it is a `Parameters` of the same names: no gradient is computed for the scene arrays not
    chosen (vertices and normals when only colours are), and no `eqx.tree_at` is written by
    hand. It works under `jax.jit` (compiling once for every value of the parameters),
    `jax.grad`, `jax.value_and_grad` and `jax.jvp`.

    Names (`PARAMETER_NAMES`):

    - materials: `ka`, `kd`, `ks`, `ke`, `kr` (M, 3), `ns` (M,) — rows `materials` only;
    - lights: `light_position`, `light_color` (L, 3) — rows `lights` only;
    - geometry: `vertices` (V, 3) — rows `vertices` only; the BVH is not rebuilt and visibility
      is not differentiated (see `fovjax.render`), so moving vertices by more than the
      secondary-ray offset leaves rays finding the old surface;
    - `ambient` (3,), `environment` (He, We, 3): the ambient light and the environment map;
    - `camera_position` (3,): the position of `view` (a `Camera`, or a `StereoRig`'s head
      centre);
    - `head_pose` (3,): yaw, pitch, roll in degrees, handed to `render_fn` as `head_pose=`.

    Example:
        ```python
        scene = fovjax.scenes.cornell_box()
        bvh = fovjax.trace.build_bvh(scene)
        frame = fovjax.render.differentiable(
            lambda arrays: render_stereo_image(arrays, bvh, rig, (0.0, 0.0, 0.0)),
            scene, ("kd", "light_color"), materials=("red", "green"))
        loss = lambda params: jnp.mean((frame(params) - target) ** 2)
        value, grads = jax.jit(jax.value_and_grad(loss))(frame.parameters)
        grads["kd"]                       # (2, 3): d loss / d Kd of the red and green walls
        ```

    Args:
        render_fn: the function to differentiate, called as `render_fn(arrays, *args,
            **kwargs)` with the `SceneArrays` first, the arguments the `Differentiable` is
            called with after them, and `view=` and `head_pose=` keywords where those are
            given here. Any JAX function of the arrays: `render_stereo_image` or `render_image`
            with the BVH, rig and options bound, or a frame of your own.
        scene: the scene the parameters come from and go into: a `Scene` (its `scene_arrays`,
            and its material names for `materials`) or `SceneArrays`.
        names: the parameters, one name or several, from `PARAMETER_NAMES`.
        view: a `Camera` or `StereoRig` handed to `render_fn` as `view=` (needed for
            `camera_position`).
        head_pose: a head pose handed to `render_fn` as `head_pose=` (a (3,) array after
            `head_pose_angles`; needed for the `head_pose` parameter).
        materials: the material rows the material parameters hold, as indices or (with a
            `Scene`) names, in the order given; None: every material.
        lights: the light rows the light parameters hold; None: every light.
        vertices: the vertex rows `vertices` holds; None: every vertex.

    Returns:
        The `Differentiable`.

    Raises:
        ValueError: for an unknown or repeated name (the message lists the valid ones), rows
            out of range, repeated or given without a parameter they select, material names
            the scene does not have, or `camera_position`/`head_pose` without `view`/
            `head_pose`.
        TypeError: for a `render_fn` that is not callable or a `view` that is neither a
            `Camera` nor a `StereoRig`.
    """
    if not callable(render_fn):
        raise TypeError(f"differentiable: render_fn must be callable, got {type(render_fn).__name__}")
    chosen = _names(names)
    arrays = scene_arrays(scene) if isinstance(scene, Scene) else scene
    if view is not None and not isinstance(view, Camera | StereoRig):
        raise TypeError(f"differentiable: view must be a Camera or a StereoRig, got {type(view).__name__}")
    if "camera_position" in chosen and view is None:
        raise ValueError(
            "differentiable: 'camera_position' is the view's position; pass view= (a Camera or StereoRig)"
        )
    pose = None if head_pose is None else head_pose_angles(head_pose)
    if "head_pose" in chosen and pose is None:
        raise ValueError(
            "differentiable: the 'head_pose' parameter needs a starting head_pose= (yaw, pitch, roll)"
        )
    material_names = scene.materials.names if isinstance(scene, Scene) else None
    n_materials = int(np.shape(arrays.kd)[0])
    material_rows = _rows(
        "materials", materials, n_materials, chosen, MATERIAL_NAMES, material_names, "material"
    )
    light_rows = _rows("lights", lights, arrays.num_lights, chosen, LIGHT_NAMES, None, "light")
    n_vertices = int(np.shape(arrays.vertices)[0])
    vertex_rows = _rows("vertices", vertices, n_vertices, chosen, VERTEX_NAMES, None, "vertex")
    return Differentiable(
        render_fn=render_fn,
        arrays=arrays,
        view=view,
        head_pose=pose,
        names=chosen,
        material_rows=material_rows,
        light_rows=light_rows,
        vertex_rows=vertex_rows,
    )


def _names(names) -> tuple[str, ...]:
    chosen = (names,) if isinstance(names, str) else tuple(names)
    if not chosen:
        raise ValueError(f"differentiable: choose at least one parameter from {', '.join(PARAMETER_NAMES)}")
    for name in chosen:
        if not isinstance(name, str) or name not in PARAMETER_NAMES:
            raise ValueError(
                f"differentiable: unknown parameter {name!r}; the parameters are {', '.join(PARAMETER_NAMES)}"
            )
    repeated = sorted({name for name in chosen if chosen.count(name) > 1})
    if repeated:
        raise ValueError(f"differentiable: parameter {', '.join(map(repr, repeated))} chosen twice")
    return chosen


def _rows(
    keyword: str,
    rows,
    count: int,
    chosen: tuple[str, ...],
    selects: tuple[str, ...],
    row_names: Sequence[str] | None,
    what: str,
) -> tuple[int, ...] | None:
    """The row indices `rows` (indices, or names looked up in `row_names`) of a leaf with
    `count` rows, checked; None for every row."""
    if rows is None:
        return None
    if not any(name in chosen for name in selects):
        raise ValueError(
            f"differentiable: {keyword}= selects rows of {', '.join(selects)}, and none of them is chosen"
        )
    if isinstance(rows, str | int | np.integer):
        rows = (rows,)
    indices = []
    for row in rows:
        if isinstance(row, str):
            if row_names is None:
                raise ValueError(
                    f"differentiable: {what} name {row!r} needs the Scene (its names); pass the Scene "
                    f"itself, or row indices"
                )
            if row not in row_names:
                raise ValueError(
                    f"differentiable: no {what} named {row!r}; the scene's are {', '.join(row_names)}"
                )
            indices.append(row_names.index(row))
        elif isinstance(row, int | np.integer) and not isinstance(row, bool):
            if not -count <= int(row) < count:
                raise ValueError(
                    f"differentiable: {what} row {int(row)} is out of range for {count} {what} rows"
                )
            indices.append(int(row) % count)
        else:
            raise ValueError(f"differentiable: {keyword}= takes row indices or names, got {row!r}")
    if not indices:
        raise ValueError(f"differentiable: {keyword}= is empty; leave it out for every {what}")
    repeated = sorted({i for i in indices if indices.count(i) > 1})
    if repeated:
        raise ValueError(f"differentiable: {keyword}= names {what} row(s) {repeated} more than once")
    return tuple(indices)
