"""thesis_repro: reproduce, figure by figure, C. Zhao's thesis on generalisation in deep RL.

Sub-modules: ``paths`` (every location), ``scales`` (the smoke/small/full table), ``cache`` (the
content-addressed run cache and job runner), ``notebooks`` (papermill execution), ``book``.
"""

import os

# The one place the kit chooses MuJoCo's offscreen renderer (EGL: no display needed); a user's own
# MUJOCO_GL wins. Set before anything imports mujoco; papermill kernels inherit it.
os.environ.setdefault("MUJOCO_GL", "egl")

__version__ = "0.1.0"
