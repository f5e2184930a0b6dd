"""Foveation methods beside the thesis's (`Foveation(method=...)`): the catalog with each
method's paper and parameters (`_catalog`) and their frame programs."""

from ._catalog import METHODS as METHODS
from ._catalog import Citation as Citation
from ._catalog import Guenter2012 as Guenter2012
from ._catalog import Thesis as Thesis
from ._catalog import Weier2016 as Weier2016
from ._catalog import as_method as as_method

__all__ = ["METHODS", "Citation", "Guenter2012", "Thesis", "Weier2016", "as_method"]
