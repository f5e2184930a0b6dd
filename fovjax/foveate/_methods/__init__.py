"""Foveation methods beside the thesis's (`Foveation(method=...)`): the catalog with each
method's paper and parameters (`_catalog`) and their frame programs."""

from ._catalog import METHODS as METHODS
from ._catalog import Citation as Citation
from ._catalog import Guenter2012 as Guenter2012
from ._catalog import Patney2016 as Patney2016
from ._catalog import Thesis as Thesis
from ._catalog import Weier2016 as Weier2016
from ._catalog import as_method as as_method
from ._catalog import method_label as method_label

__all__ = [
    "METHODS",
    "Citation",
    "Guenter2012",
    "Patney2016",
    "Thesis",
    "Weier2016",
    "as_method",
    "method_label",
]
