"""Core: locations, checks, the scale table, the thesis's numbers, code stamps, the run store and its backends."""
