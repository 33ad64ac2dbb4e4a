"""An example plugin of snell_bench: a method (:mod:`.methods`) and a metric (:mod:`.metrics`), each
one file, registered by the entry points of this package's ``pyproject.toml``."""
