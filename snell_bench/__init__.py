"""snell_bench: physically correct transparent objects in generated images (Snellcaster), reproduced
and measured."""

__version__ = "0.1.0"
