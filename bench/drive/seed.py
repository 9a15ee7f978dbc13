"""The noise seed of the bench's own datasets when none is given (`bench data`, the datasets `bench run` generates):
here, with nothing but the standard library, so `bench data --help` names it without importing the generator
(scipy)."""

DEFAULT_SEED = 20240
