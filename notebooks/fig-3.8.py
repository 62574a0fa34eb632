# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: percent
# ---

# %% [markdown]
# # Figure 3.8 — Generalisation of the selected learners on all five tasks
#
# The thesis's caption and claims open the book page (quoted with line numbers from
# `data/thesis/claims.yaml`, key `fig-3.8`); the verdicts at the end judge each claim on our numbers.
#
# Curves: testing return vs σ (line: the mean over training seeds of each seed's mean over its testing rollouts;
# band: the 95 % confidence interval of that mean across training seeds, t-interval, none with one seed), one
# row per task, one column per test type; the same evaluation jobs as the tables. The thesis gives curves only,
# so its AUCs (Tables 3.4-3.7) are shown beside ours in the table below.
# Logic: `thesis_repro.figures.ch3_curves` (on the runs and cells of `ch3_tables`).
# PPO-MAML-DG's outer update is optimised as PPO (epochs x minibatches of Alg 1's first-order objective), a
# stated deviation from Alg 1 read literally, which takes one Adam step per iteration and did not learn at
# `small` (README, "MAML-DG's outer update"); Reptile-DG follows Alg 2 as written.

# %% tags=["parameters"]
SCALE = "small"

# %%
from thesis_repro import claims
from thesis_repro.book import pages
from thesis_repro.figures import ch3_curves, ch3_tables, plot

settings = ch3_tables.checked_settings("3.8", SCALE)
print(pages.runs_summary("3.8", SCALE))
print(ch3_tables.describe_budget(settings))
res = ch3_tables.run(settings, n_jobs=settings["n_jobs"])
fig = ch3_curves.plot_curves(res, settings, "Fig 3.8")
plot.save(fig, SCALE, "fig-3.8")

# %%
comp = ch3_tables.compare("3.8", ch3_tables.our_cells(res), settings, ci=ch3_tables.our_ci(res))
comp.style("Testing AUC of the curves: thesis (Tables 3.4-3.7) beside reproduced")

# %%
comp.ci_style("Testing AUC, reproduced: across training seeds, mean [95 % CI] (seeds)")

# %% [markdown]
# ## Does the claim reproduce at this scale?

# %%
_ = claims.judge_page("fig-3.8", SCALE, ch3_tables.seed_frames(res), pages.claim_meta("3.8", settings))
