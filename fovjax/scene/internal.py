"""What sibling packages use of `fovjax.scene` beyond its public API (the handlers that draw the
sub-pixel jitter natively need to know whether they can)."""

from ._camera import key_words as key_words
from ._camera import per_sample_threefry as per_sample_threefry

__all__ = ["key_words", "per_sample_threefry"]
