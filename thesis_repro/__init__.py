"""thesis_repro: reproduce, figure by figure, C. Zhao's thesis on generalisation in deep RL.

Sub-modules: ``paths`` (every location), ``scales`` (the smoke/small/full table), ``cache`` (the
content-addressed run cache and job runner), ``notebooks`` (papermill execution), ``book``.
"""

__version__ = "0.1.0"
