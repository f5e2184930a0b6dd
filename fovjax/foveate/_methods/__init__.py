"""Foveation methods (`Foveation(method=...)`): the protocol every method implements
(`_base`), the registry by name (`_registry`), the methods fovjax ships with their papers and
parameters (`_catalog`) and their frame programs (one module each)."""

from ._base import THESIS_OPTIONS as THESIS_OPTIONS
from ._base import AbstractFoveationMethod as AbstractFoveationMethod
from ._base import Citation as Citation
from ._base import FrameInputs as FrameInputs
from ._catalog import Guenter2012 as Guenter2012
from ._catalog import Patney2016 as Patney2016
from ._catalog import Thesis as Thesis
from ._catalog import Weier2016 as Weier2016
from ._registry import METHODS as METHODS
from ._registry import as_method as as_method
from ._registry import method_label as method_label
from ._registry import register_method as register_method

__all__ = [
    "THESIS_OPTIONS",
    "AbstractFoveationMethod",
    "Citation",
    "FrameInputs",
    "METHODS",
    "Guenter2012",
    "Patney2016",
    "Thesis",
    "Weier2016",
    "as_method",
    "method_label",
    "register_method",
]
