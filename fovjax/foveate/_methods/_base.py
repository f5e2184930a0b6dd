"""The foveation-method protocol: what a method gives `FoveatedRenderer` (`AbstractFoveationMethod`),
the inputs its frame program is called with (`FrameInputs`) and its paper (`Citation`).

Light on purpose: `Foveation` (`fovjax.foveate._config`) imports this module, and the frame
programs import `Foveation`, so a method's class imports its frame program only when a frame is
traced.
"""

# No `from __future__ import annotations`: equinox reads `AbstractClassVar` from the
# annotation object (a string one it refuses), so the annotations of names imported only for
# type checking are strings here.
import abc
import dataclasses
from typing import TYPE_CHECKING, Any, ClassVar, NamedTuple, TypeAlias

import equinox as eqx

if TYPE_CHECKING:  # equinox's advice for pyright (its issue 4965)
    from typing import ClassVar as AbstractClassVar
else:
    from equinox import AbstractClassVar

if TYPE_CHECKING:  # annotations only: these modules import this one
    from jaxtyping import Array, Float, Int, PRNGKeyArray

    from ...render import SceneArrays, StereoRig
    from ...render.internal import ShadingClasses
    from ...trace import BVH
    from .._config import Foveation
    from .._frame import FoveatedOutputs, FrameOptions
    from .._lod import LODTables
    from .._renderer import FoveatedRenderer

# What a method carries from frame to frame: any pytree of arrays of static shapes (None: nothing).
History: TypeAlias = Any

# The `Foveation` options only the thesis's frame had when they were added: a method refuses
# those it does not read (`AbstractFoveationMethod.thesis_options`). "rule" is refused by the
# comparisons only (`Foveation.rule` has a default, so it is always set).
THESIS_OPTIONS = ("rule", "fidelity", "ray_budget", "max_periphery_deg", "fovea_tile_deg", "grid_tile")


@dataclasses.dataclass(frozen=True)
class Citation:
    """A method's paper. The DOI is taken only from a source that could be read (the thesis's
    bibliography or the publisher's pages); None where none was."""

    authors: str
    year: int
    title: str
    venue: str
    doi: str | None

    def __str__(self) -> str:
        doi = f" doi:{self.doi}" if self.doi else ""
        return f"{self.authors} ({self.year}). {self.title}. {self.venue}.{doi}"


class FrameInputs(NamedTuple):
    """A frame program's traced inputs, as `FoveatedRenderer` prepares them: the scene's arrays
    and BVH, the rig, this frame's head pose ((yaw, pitch, roll) degrees), gaze ((2, 2):
    per-eye normalised display coordinates), key and foveation (its thresholds traced), and the
    per-region tables of `Foveation.fidelity` (`lod`, `shading`: None without fidelity)."""

    scene: "SceneArrays"
    bvh: "BVH"
    rig: "StereoRig"
    head_pose: "Float[Array, ' 3']"
    gaze: "Float[Array, '2 2']"
    key: "PRNGKeyArray"
    foveation: "Foveation"
    lod: "LODTables | None"
    shading: "ShadingClasses | None"


class AbstractFoveationMethod(eqx.Module):
    """A foveation method: the extension point of `Foveation(method=...)`.

    A method is an `eqx.Module` whose fields are its paper's parameters, hashable Python values
    (it is a static part of `Foveation`: another value compiles another program), checked in
    `__check_init__`. Its class is registered by name (`register_method`), which makes the name
    usable wherever a method is named (`Foveation(method=name)`, `ThresholdSweep(methods=)`,
    `fovjax compare --methods`). `FoveatedRenderer` calls it through this protocol only:

    - `frame(inputs, history, options=...)`: the frame program, pure and jitted with `options`
      static; returns (the frame's `FoveatedOutputs`, the pixels shown from the history as an
      int32 scalar or None, the next history);
    - `empty_history(eye_height, eye_width)`: the history after a reset (a temporal method's:
      the renderer keeps each frame's for the next, `render(reset=True)` starts again from
      this); None for a method that keeps none;
    - `frame_options(renderer, jitter=, diagnostics=)`: the frame program's static
      `FrameOptions`;
    - class variables: `name` (the registry's key), `citation` (a `Citation`, or None),
      `temporal` (frames carry a history), `thesis_options` (which options of the thesis's
      frame, `THESIS_OPTIONS`, this frame reads: `Foveation` refuses the others),
      `batches` (`FoveatedRenderer.render_batch` maps the frame program over a batch);
    - `widens_fovea`: whether the gaze tracker's fallback widens this method's thresholds;
    - `label()`: the name and the parameters set apart from the defaults.

    CONTRIBUTING.md ("Add a foveation method") has a complete small method.
    """

    name: AbstractClassVar[str]
    citation: AbstractClassVar[Citation | None]
    temporal: ClassVar[bool] = False
    thesis_options: ClassVar[frozenset[str]] = frozenset()
    batches: ClassVar[bool] = False

    @abc.abstractmethod
    def frame(
        self, inputs: FrameInputs, history: History, *, options: "FrameOptions"
    ) -> "tuple[FoveatedOutputs, Int[Array, ''] | None, History]":
        """One stereo frame from the previous frame's `history` (`empty_history` after a reset):
        (the frame's outputs, the pixels shown from the history or None, this frame's history).
        Pure: traced once per configuration, with `options` static."""

    def empty_history(self, eye_height: int, eye_width: int) -> History:
        """The history after a reset, for eyes of `eye_height` × `eye_width` pixels (None: the
        method keeps none; a temporal method's frames start from this)."""
        return None

    def frame_options(
        self, renderer: "FoveatedRenderer", *, jitter: bool, diagnostics: tuple[str, ...]
    ) -> "FrameOptions":
        """The frame program's static options for `renderer`: its samples per pixel and render
        config, the frame's `jitter` and `diagnostics` (no ray-slot budget and no tiles: those
        are the thesis's frame's)."""
        from .._frame import FrameOptions

        return FrameOptions(
            spp=renderer.foveation.spp, jitter=jitter, config=renderer.config, diagnostics=diagnostics
        )

    @property
    def entry(self) -> str:
        """The frame program's entry in the compile cache (`fovjax.render.compile_cache_info`)."""
        return f"foveated-{self.name}"

    @property
    def widens_fovea(self) -> bool:
        """Whether the gaze tracker's fallback widens this method's thresholds when tracking
        degrades or is lost (`fovjax.devices.widen_thresholds`): True, the thesis's fallback,
        unless the method covers the widening otherwise (see `Weier2016`)."""
        return True

    def label(self) -> str:
        """The method's name and the parameters it sets apart from its class's defaults, as a
        comparison labels its rows: "weier2016", "weier2016(widened_fovea='trace')"."""
        default = type(self)()
        changed = [
            f"{f.name}={getattr(self, f.name)!r}"
            for f in dataclasses.fields(self)
            if getattr(self, f.name) != getattr(default, f.name)
        ]
        return self.name + (f"({', '.join(changed)})" if changed else "")
