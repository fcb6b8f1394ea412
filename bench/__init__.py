"""Run-time-vs-error benchmarks: ``python -m bench <name> [args]`` (``--list`` to see them).

Each benchmark is a module ``bench/<name>.py`` with ``main(argv) -> int`` that prints a
table of run time and error against a reference and writes a PNG plot (and the table
as Markdown) to ``bench/out/``.  Benchmarks are not part of the test run.
"""
