"""The command line: ``python -m thesis_repro`` and ``make verify``."""
