"""The foveation methods by name: `register_method` adds a class, `METHODS` reads them,
`as_method` turns a name or an instance into a method (`Foveation.method`'s converter)."""

from __future__ import annotations

import re
import types
from collections.abc import Mapping
from typing import TypeVar

from ._base import THESIS_OPTIONS, AbstractFoveationMethod, Citation

_REGISTRY: dict[str, type[AbstractFoveationMethod]] = {}

METHODS: Mapping[str, type[AbstractFoveationMethod]] = types.MappingProxyType(_REGISTRY)
"""The registered foveation methods by name (`Foveation(method=name)`, `fovjax compare
--methods`), in the order they were registered (read-only: `register_method` adds one)."""

_NAME = re.compile(r"[a-z][a-z0-9_-]*")
_Method = TypeVar("_Method", bound=AbstractFoveationMethod)


def register_method(cls: type[_Method]) -> type[_Method]:
    """Register a foveation method class under its `name` (a class decorator; returns `cls`).

    Args:
        cls: a concrete subclass of `AbstractFoveationMethod` whose defaults are valid
            (`Foveation(method=name)` makes one with them).

    Returns:
        `cls`, now in `METHODS`.

    Raises:
        TypeError: `cls` is not a concrete subclass of `AbstractFoveationMethod`.
        ValueError: its `name` is not lower-case letters, digits, "-" and "_" starting with a
            letter, or is taken by another class; its `citation` is not a `Citation` or None; its
            `thesis_options` are not names of `THESIS_OPTIONS`; `temporal` and `empty_history`
            disagree; it is both temporal and `batches`; or its defaults are refused.
    """
    if not (isinstance(cls, type) and issubclass(cls, AbstractFoveationMethod)):
        raise TypeError(f"register_method: expected a subclass of AbstractFoveationMethod, got {cls!r}")
    where = f"register_method({cls.__name__})"
    # Equinox keeps abstract class variables and fields apart from abstract methods.
    missing = [
        name
        for kind in ("__abstractmethods__", "__abstractclassvars__", "__abstractvars__")
        for name in sorted(getattr(cls, kind, ()))
    ]
    if missing:
        raise TypeError(f"{where}: the class is abstract: define {', '.join(missing)}")
    name = cls.name
    if not (isinstance(name, str) and _NAME.fullmatch(name)):
        raise ValueError(
            f"{where}: name {name!r}: expected lower-case letters, digits, '-' and '_', "
            "starting with a letter"
        )
    taken = _REGISTRY.get(name)
    if taken is not None and taken is not cls:
        raise ValueError(f"{where}: name {name!r} is taken by {taken.__module__}.{taken.__qualname__}")
    if not (cls.citation is None or isinstance(cls.citation, Citation)):
        raise ValueError(f"{where}: citation {cls.citation!r}: expected a Citation or None")
    unknown = sorted(set(cls.thesis_options) - set(THESIS_OPTIONS))
    if unknown:
        raise ValueError(f"{where}: thesis_options {unknown}: expected names of {THESIS_OPTIONS}")
    keeps_history = cls.empty_history is not AbstractFoveationMethod.empty_history
    if cls.temporal != keeps_history:
        raise ValueError(
            f"{where}: temporal is {cls.temporal} but the class "
            f"{'defines' if keeps_history else 'does not define'} empty_history: expected both or neither"
        )
    if cls.temporal and cls.batches:
        raise ValueError(f"{where}: a temporal method's frames follow one another: expected batches False")
    try:
        cls()
    except (TypeError, ValueError) as e:
        raise ValueError(f"{where}: its defaults are refused: {e}") from e
    _REGISTRY[name] = cls
    return cls


def as_method(method: object) -> AbstractFoveationMethod:
    """A method instance from a name of `METHODS` (the class's defaults) or an instance of a
    registered class."""
    if isinstance(method, str):
        if method not in METHODS:
            raise ValueError(f"Foveation.method must be one of {tuple(METHODS)}, got {method!r}")
        return METHODS[method]()
    if isinstance(method, AbstractFoveationMethod):
        if METHODS.get(method.name) is not type(method):
            raise ValueError(
                f"Foveation.method: {type(method).__qualname__} (name {method.name!r}) is not a registered "
                f"method: register it with fovjax.foveate.register_method (registered: {tuple(METHODS)})"
            )
        return method
    raise ValueError(
        f"Foveation.method must be a name of {tuple(METHODS)} or an instance of "
        f"{', '.join(c.__name__ for c in METHODS.values())}, got {method!r}"
    )


def method_label(method: AbstractFoveationMethod) -> str:
    """The method's name and the parameters it sets apart from its class's defaults, as a
    comparison labels its rows: "weier2016", "weier2016(widened_fovea='trace')"
    (`AbstractFoveationMethod.label`)."""
    return method.label()
