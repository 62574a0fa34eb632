# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: percent
# ---

# %% [markdown]
# # Figure 3.2 — Overfitting occurs in deep RL

# %% [markdown]
# The thesis's caption and claims open the book page (quoted with line numbers from
# `data/thesis/claims.yaml`, key `fig-3.2`); the verdicts at the end judge each claim on our numbers.
#
# Here PPO (Appendix A hyperparameters) saves a policy snapshot every `snapshot_every` steps; each snapshot is
# tested under observation noise over the σ grid of the scale table (AUC, Eq 3.6) and compared with the mean
# return of the last 100 training episodes at that point. The thesis gives only the curve, so the comparison is
# of shape. The caption's "with non-deterministic observations" is read as the *testing* condition (the AUC is
# under observation noise); training is on the deterministic task, as for every chapter-3 benchmark policy
# (§3.3.1 trains on the default environment and tests under noise). The markers are means over training seeds
# and the thick line their moving average over `smooth_snapshots` consecutive snapshots; with several seeds a thin
# line shows each seed (its own moving average, and its training return); the verdict compares the early, middle
# and late quarters of each seed's snapshots (`thesis_repro.claims`), so one noisy snapshot makes neither a peak
# nor the end. Logic: `thesis_repro.figures.ch3`.

# %% tags=["parameters"]
SCALE = "small"

# %%
import matplotlib.pyplot as plt
import seaborn as sns

from thesis_repro import claims, figures
from thesis_repro.book import pages
from thesis_repro.figures import ch3, plot
from thesis_repro.learners import iteration_steps

settings = figures.settings("3.2", SCALE)
print(pages.runs_summary("3.2", SCALE))
curve = ch3.overfitting_curve(settings, n_jobs=settings["n_jobs"])
ch3.curve_style(curve)

# %%
mean = curve.groupby("iteration")[["train_return", "test_auc"]].mean().reset_index()
steps = iteration_steps(ch3.overfitting_configs(settings)[0])
fig, ax = plt.subplots(figsize=(6.5, 4))
ax2 = ax.twinx()
w = settings.get("smooth_snapshots", 1)  # the thick line (the verdict uses quarters of the snapshots)
smooth = curve.assign(test_auc=curve.groupby("seed").test_auc.transform(lambda x: x.rolling(w, center=True).mean()))
seeds = dict(x="iteration", units="seed", estimator=None, lw=0.8, alpha=0.35, legend=False)  # thin: one per seed
sns.lineplot(data=smooth, y="test_auc", color="C0", ax=ax, **seeds)
sns.lineplot(data=curve, y="train_return", color="C3", ax=ax2, **seeds)
ax.plot(mean.iteration, mean.test_auc, "C0o", ms=3, alpha=0.5, label="testing AUC (obs noise), reproduced")
ax.plot(mean.iteration, mean.test_auc.rolling(w, center=True).mean(), "C0-", lw=2.5, label=f"its {w}-snapshot mean")
ax2.plot(mean.iteration, mean.train_return, "C3-s", ms=3, label="training return, reproduced")
n_seeds = curve.seed.nunique()
title = f"{settings['env']} PPO ({SCALE}): mean over {n_seeds} training seed(s)"
if n_seeds > 1:
    title += f"\nthin lines: each seed ({w}-snapshot mean of its AUC; its training return)"
ax.set(xlabel=f"PPO iteration ({steps} steps)", ylabel="testing AUC", title=title)
ax.title.set_fontsize(9)
ax2.set_ylabel("training return")
ax2.grid(False)
handles = ax.get_legend_handles_labels()[0] + ax2.get_legend_handles_labels()[0]
ax.legend(handles, [h.get_label() for h in handles], loc="lower right", fontsize=8)
fig.tight_layout()
plot.save(fig, SCALE, "fig-3.2", dpi=120)

# %% [markdown]
# ## Does the claim reproduce at this scale?

# %%
_ = claims.judge_page("fig-3.2", SCALE, {"curve": curve}, pages.claim_meta("3.2", settings))
