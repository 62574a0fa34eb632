# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: percent
# ---

# %% [markdown]
# # Figure 5.5 — tensor transfer vs ELLA, RBF-ELLA and FCNN

# %% [markdown]
# The thesis's caption and claims open the book page (quoted with line numbers from
# `data/thesis/claims.yaml`, key `fig-5.5`); the verdicts at the end judge each claim on our numbers.
#
# Competitors (`thesis_repro.arm.baselines`): **ELLA** (linear policy on [x_t, t]), **RBF-ELLA** (linear on a
# 5 × 5 × 5 RBF tiling) and **FCNN** ([x_t, t] → 8 ReLU → actions). Each learns its own source tasks the same
# automatic way as ours, then transfers ELLA-style: a low-rank basis L from the SVD of the stacked source
# parameters, the target alternating CMA-ES on s and on L (ELLA's own second-order updates need a gradient model
# that CMA-ES policy search does not have). Settings are shared with Fig 5.4, so the tensor runs are reused.
# Caveat: CMA-ES uses the same σ0 for every policy class, so the competitors' input/output scalings (our choice,
# see `ClosedLoopPolicy`) set their effective exploration; the thesis does not give its scalings.

# %% tags=["parameters"]
SCALE = "small"

# %%
import matplotlib.pyplot as plt
import seaborn as sns

from thesis_repro import claims, figures
from thesis_repro.book import pages
from thesis_repro.evaluation import tables
from thesis_repro.figures import ch5, plot

settings = figures.settings("5.5", SCALE)
print(pages.runs_summary("5.5", SCALE))
METHODS = list(ch5.FIG55_METHODS)
summary, curves = ch5.run_grid(settings, METHODS, n_jobs=settings["n_jobs"])
ch5.strategy_means(summary, METHODS).round(3)

# %% [markdown]
# ## (a) learning curve, Cast → BIC; (b) average total cost and % of pairs won (reproduced)

# %%
src, tgt, d = ch5.cast_to_bic(curves, settings["families"])
per_seed = ch5.strategy_seed_means(summary, METHODS)
wins = ch5.pair_wins(summary, METHODS)
band = plot.seed_band(d, ["strategy", "trials"]).replace("band:", "(a) band, (b) bars:")
by_strategy = dict(hue="strategy", hue_order=METHODS, errorbar=tables.t_errorbar)  # per-seed rows
fig, axes = plt.subplots(1, 3, figsize=(15, 4.2))
sns.lineplot(data=d, x="trials", y="cost", ax=axes[0], **by_strategy)
axes[0].set(title=f"(a) reproduced: {src} → {tgt}", xlabel="trials per target task", ylabel="mean population cost")
sns.barplot(data=per_seed, x="strategy", y="total_cost", order=METHODS, ax=axes[1], legend=False, **by_strategy)
axes[1].set(title="(b) reproduced: average total cost (lower is better)", ylabel="average total cost of learning")
sns.barplot(x=wins.index, y=wins.values, hue=wins.index, ax=axes[2], legend=False)
axes[2].set(
    title="(b) reproduced: % of pairs won\n(smallest total cost, mean over seeds)",
    xlabel="strategy",
    ylabel="% of pairs won (smallest total cost)",
)
for ax in axes:
    ax.title.set_fontsize(9)
fig.suptitle(band, fontsize=9)
fig.tight_layout()
plot.save(fig, SCALE, "fig-5.5", dpi=120)

# %% [markdown]
# ## Do the claims reproduce at this scale?

# %%
_ = claims.judge_page("fig-5.5", SCALE, {"summary": summary, "curves": curves}, pages.claim_meta("5.5", settings))
