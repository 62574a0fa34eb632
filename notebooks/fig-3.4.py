# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: percent
# ---

# %% [markdown]
# # Figure 3.4 — Generalisation of the basic learners on Walker2d
#
# The thesis's caption and claims open the book page (quoted with line numbers from
# `data/thesis/claims.yaml`, key `fig-3.4`); the verdicts at the end judge each claim on our numbers.
#
# Top: testing return vs σ (line: the mean over training seeds of each seed's mean over its testing rollouts;
# band: the 95 % confidence interval of that mean across training seeds, t-interval, none with one seed) for
# PPO, TRPO, DDPG, SAC. Bottom: mean testing return over body-mass × wind shifts in σ units (mass ratio 1 + d;
# wind d · 9.81 m/s², the units of the `env`/`dom` sampling), training domain at (0, 0). The thesis gives curves
# only; its AUCs (Table 3.4) are shown beside ours. Logic: `thesis_repro.figures.ch3_curves` (on the runs and
# cells of `ch3_tables`).

# %% tags=["parameters"]
SCALE = "small"

# %%
from thesis_repro import claims
from thesis_repro.book import pages
from thesis_repro.figures import ch3_curves, ch3_tables, plot

settings = ch3_tables.checked_settings("3.4", SCALE)
print(pages.runs_summary("3.4", SCALE))
print(ch3_tables.describe_budget(settings))
res = ch3_tables.run(settings, n_jobs=settings["n_jobs"])
heat = ch3_curves.run_heat(settings, n_jobs=settings["n_jobs"])
fig = ch3_curves.plot_curves(res, settings, "Fig 3.4 (top)")
plot.save(fig, SCALE, "fig-3.4-curves")

# %%
fig = ch3_curves.plot_heat(heat, settings)
plot.save(fig, SCALE, "fig-3.4-heatmaps")
ch3_curves.heat_summary_style(
    ch3_curves.heat_summary(heat),
    settings,
    "Heat maps, reproduced: mean testing return at the training domain (centre) and its drop (centre minus the "
    "mean return) at the largest shift of one factor, the other at 0, and over the outer ring of the grid",
)

# %% [markdown]
# The same summary across **training seeds** (per seed its centre and drops, then the mean over seeds and its
# 95 % t-interval; one seed: no interval).

# %%
ch3_curves.heat_summary_style(
    ch3_curves.heat_summary_ci(heat), settings, "Heat maps, reproduced, across training seeds: mean [95 % CI] (seeds)"
)

# %%
comp = ch3_tables.compare("3.4", ch3_tables.our_cells(res), settings, ci=ch3_tables.our_ci(res))
comp.style("Testing AUC on the task of Fig 3.4: thesis (Table 3.4) beside reproduced")

# %%
comp.ci_style("Testing AUC, reproduced: across training seeds, mean [95 % CI] (seeds)")

# %% [markdown]
# ## Does the claim reproduce at this scale?

# %%
_ = claims.judge_page(
    "fig-3.4",
    SCALE,
    {**ch3_tables.seed_frames(res), "heat": ch3_curves.heat_seeds(heat)},
    pages.claim_meta("3.4", settings),
)
