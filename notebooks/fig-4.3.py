# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: percent
# ---

# %% [markdown]
# # Figure 4.3 — Testing return vs wind speed (Walker2d), four training conditions
#
# Thesis claim (§4.3.3): evaluated with wind ξ ∈ [−5, 5] (wider than training), kl_avg is competitive
# in the easiest condition and more robust than params_avg and joint when training is harder (wider
# wind range and/or c_a = 1), i.e. it extrapolates better. The policies are the cached runs of Fig 4.1;
# each is tested with its mean action over `test_rollouts` testing seeds per wind speed. All numbers
# below are **reproduced** (the thesis gives only plots).

# %% tags=["parameters"]
SCALE = "small"

# %%
import matplotlib.pyplot as plt
import seaborn as sns

from thesis_repro import paths
from thesis_repro.mdl import experiments as ex
from thesis_repro.scales import figure_settings

settings = figure_settings("4.3", SCALE)
conds = ex.conditions("4.3", settings["panels"])
runs = ex.train_runs(settings, settings["algos"], conds, n_jobs=settings["n_jobs"])
wind = ex.evaluate_runs(runs, "wind", settings["winds"], settings["test_rollouts"], n_jobs=settings["n_jobs"])
wind["source"] = "reproduced"

# %%
fig, axes = plt.subplots(1, len(conds), figsize=(4 * len(conds), 3.5), sharey=True, squeeze=False)
for j, cond in enumerate(conds):
    ax = axes[0, j]
    sns.lineplot(
        data=wind[wind["panel"] == cond["panel"]],
        x="value",
        y="return",
        hue="algo",
        hue_order=settings["algos"],
        marker="o",
        ax=ax,
        legend=(j == 0),
    )
    ax.axvspan(*cond["wind"], color="grey", alpha=0.15)
    ax.set_title(f"({cond['panel']}) {ex.label(cond)}")
    ax.set_xlabel("testing wind ξ")
    ax.set_ylabel("testing return (reproduced)")
fig.suptitle(f"Fig 4.3 reproduced — {settings['env']}, scale={SCALE}")
fig.tight_layout()
out = paths.figures(SCALE) / "fig-4.3.png"
fig.savefig(out, dpi=100)
print("saved", out)

# %% [markdown]
# ## Does the claim hold at this scale?
# Mean testing return over the whole wind grid, per condition (reproduced).

# %%
table = ex.compare(wind, "return")
print(table)
lines, holds = ex.verdict(table, easy=("a",), what="mean testing return over winds")
print("\n".join(lines))
print(
    f"Conclusion (reproduced, scale={SCALE}): kl_avg generalising better across wind speeds in the harder "
    f"conditions {'HOLDS' if holds else 'does NOT hold'} here."
)
print(ex.caveat(settings))
