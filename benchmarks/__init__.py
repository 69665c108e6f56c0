"""Benchmarks of ``make bench`` (``python -m phrt.cli.bench``): not part of the extension (the
build excludes this folder), they import the core like any user of it."""
