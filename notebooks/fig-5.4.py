# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: percent
# ---

# %% [markdown]
# # Figure 5.4 — transfer strategies on the 2-D arm: learning curves and the 4 × 4 grid

# %% [markdown]
# The thesis's caption and claims open the book page (quoted with line numbers from
# `data/thesis/claims.yaml`, key `fig-5.4`); the verdicts at the end judge each claim on our numbers.
#
# Targets are learned by CMA-ES (σ0 = 0.01) from **Scratch**, **Direct** (warm start from a random learned
# source), **Matrix** (SVD of the DA × P source matrix) or **Tensor** transfer (HOSVD of the D × A × P source
# tensor, Algorithm 5). Differences from the thesis: its source tasks came from demonstrations + MTL RL; ours
# are learned automatically (CMA-ES per task on the simulator's shaped cost, then constructive MTL refinement
# of the Tucker factors). Targets use the thesis's cost (Eq 5.12) only; every strategy gets the same number of
# trials. Learning curves: top row over **all** target tasks, bottom row over the targets that succeeded at the
# end only (the thesis's convention). There are no transcribed thesis numbers (plot only): we judge the claims.

# %% tags=["parameters"]
SCALE = "small"

# %%
import matplotlib.pyplot as plt
import seaborn as sns

from thesis_repro import claims, figures
from thesis_repro.book import pages
from thesis_repro.evaluation import tables
from thesis_repro.figures import ch5, plot

settings = figures.settings("5.4", SCALE)
print(pages.runs_summary("5.4", SCALE))
summary, curves = ch5.run_grid(settings, ch5.TRANSFER, n_jobs=settings["n_jobs"])
ch5.strategy_means(summary, ch5.TRANSFER).round(3)

# %% [markdown]
# ## (a) learning curves, every source → BIC (reproduced)

# %%
families = settings["families"]
target = "bic" if "bic" in families else families[-1]
band = plot.seed_band(curves, ["source", "target", "strategy", "trials"])
by_strategy = dict(hue="strategy", hue_order=list(ch5.TRANSFER), errorbar=tables.t_errorbar)  # per-seed rows
fig, axes = plt.subplots(2, len(families), figsize=(4 * len(families), 6.4), sharey="row", squeeze=False)
for row, (column, what) in enumerate([("cost", "all targets"), ("cost_successful", "successful targets only")]):
    for ax, src in zip(axes[row], families, strict=True):
        d = curves[(curves.source == src) & (curves.target == target)].dropna(subset=[column])
        if len(d):
            sns.lineplot(data=d, x="trials", y=column, ax=ax, **by_strategy)
        ax.set(title=f"reproduced: {src} → {target} ({what})", xlabel="trials per target task")
        ax.title.set_fontsize(9)
        if ax.get_legend() is not None and (row, src) != (0, families[0]):
            ax.get_legend().remove()
    axes[row, 0].set_ylabel(f"mean population cost\n({what})")
fig.suptitle(band, fontsize=9)
fig.tight_layout()
plot.save(fig, SCALE, "fig-5.4a", dpi=120)

# %% [markdown]
# ## (b) total cost of learning and success rate at convergence, all pairs (reproduced)

# %%
bars = plot.seed_band(summary, ["pair", "strategy"]).replace("band", "bars")
fig, axes = plt.subplots(1, 2, figsize=(12, 0.35 * summary.pair.nunique() + 2.5), sharey=True)
for ax, column, xlabel in zip(
    axes,
    ["total_cost", "success_rate"],
    ["total cost of learning (sum over trials), reproduced", "success rate at convergence, reproduced"],
    strict=True,
):
    sns.barplot(data=summary, y="pair", x=column, ax=ax, **by_strategy)
    ax.set_xlabel(xlabel)
axes[1].get_legend().remove()
fig.suptitle(bars, fontsize=9)
fig.tight_layout()
plot.save(fig, SCALE, "fig-5.4b", dpi=120)

# %% [markdown]
# ## Do the claims reproduce at this scale?

# %%
_ = claims.judge_page("fig-5.4", SCALE, {"summary": summary, "curves": curves}, pages.claim_meta("5.4", settings))
