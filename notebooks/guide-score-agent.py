# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: percent
# ---

# %% [markdown]
# # Score your own agent
#
# The kit's pieces work on your own agent: this page trains a small PPO agent with Stable-Baselines3 (a
# stand-in for yours), scores it under the chapter-3 protocol of this scale with `score_model` (the book's σ
# grid, testing rollouts, episode length and testing seeds) and puts it beside every chapter-3 learner the kit
# ships on the same task with `compare_with_shipped`: the testing AUC (Eq 3.6) with 95 % confidence intervals
# across training seeds, as the ledger computes them, and a figure in the style of Fig 3.4.
#
# At scale `small` the learners beside yours are the shipped reference runs (nothing of theirs is trained); at
# `smoke` (seconds, for CI) any that are not cached are trained at smoke's budget first. Every number below is
# computed by the kit (*reproduced*); this is a guide, not a thesis item, so it has no verdict.
#
# For your own agent, replace the training cell by your models, one per training seed (`PPO.load("seed0.zip")`
# or `thesis_repro.book.agent.load_sb3`). From the command line:
# `python -m thesis_repro score seed0.zip seed1.zip --task InvertedPendulum --scale small --figure cmp.png`.

# %% tags=["parameters"]
SCALE = "small"
TASK = "InvertedPendulum"  # any of the five tasks
SEEDS = 2  # training seeds of your agent (one model each; two or more give a confidence interval)
TIMESTEPS = None  # PPO's training steps per seed; None: this scale's (thesis_repro.book.agent.GUIDE_PPO)

# %%
import torch
from stable_baselines3 import PPO

from thesis_repro.book.agent import compare_with_shipped, guide_settings, score_model
from thesis_repro.core import paths

torch.set_num_threads(1)  # one thread, as the kit's own runs: small networks train faster that way on a CPU
guide = guide_settings(SCALE, TASK, TIMESTEPS)
print(guide["note"])

# %% [markdown]
# ## 1. Your agent: one model per training seed

# %%
models = [
    PPO("MlpPolicy", guide["gym_id"], seed=seed, device="cpu", **guide["ppo"]).learn(guide["timesteps"])
    for seed in range(SEEDS)
]

# %% [markdown]
# ## 2. Its testing AUC under the book's protocol
#
# One line per test type (observation, action and environment noise, domain shift): the mean AUC over your
# models and its 95 % t-interval across them (reproduced).

# %%
scores = score_model(models, TASK, scale=SCALE)
print(scores)

# %% [markdown]
# ## 3. Beside every learner the kit ships on this task
#
# The same σ grid, rollouts and testing seeds for every row: mean AUC [95 % CI] (training seeds), reproduced.

# %%
comparison = compare_with_shipped(scores, compute_missing=guide["compute_missing"])
print(comparison)

# %%
out = paths.figures_dir(SCALE) / "guide-score-agent.png"
out.parent.mkdir(parents=True, exist_ok=True)
comparison.figure.savefig(out, dpi=100)
print("saved", out)
