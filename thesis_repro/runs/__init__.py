"""Runs: what each figure needs, what it costs, the reference-run generator, the shipped layer and its checks."""
