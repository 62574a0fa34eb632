# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: percent
# ---

# %% [markdown]
# # Figure 4.3 — Testing return vs wind speed (Walker2d), four training conditions

# %% [markdown]
# The thesis's caption and claims open the book page (quoted with line numbers from
# `data/thesis/claims.yaml`, key `fig-4.3`); the verdicts at the end judge each claim on our numbers.
#
# The policies are the cached runs of Fig 4.1; each is tested with its mean action over `test_rollouts`
# testing seeds per wind speed. All numbers are **reproduced** (the thesis gives only plots).
#
# Learners: the thesis's kl_avg (Alg 3 with Eq 4.11), kl_exact (ours: the exact minimiser of Eq 4.7
# from params_avg), params_avg (Eq 4.6) and joint (PPO on the merged batch). Each claim is judged twice, for
# kl_avg and for kl_exact (counted beyond the thesis), each against params_avg and joint only (`claims.yaml`).
#
# Lines: the mean over training seeds of each seed's mean testing return over its rollouts; band: the 95 %
# confidence interval of that mean across training seeds (t-interval, n = seeds; none with one seed), as the figure
# title says.

# %% tags=["parameters"]
SCALE = "small"

# %%
from thesis_repro import claims, figures
from thesis_repro.book import pages
from thesis_repro.figures import ch4, plot

settings = figures.settings("4.3", SCALE)
print(pages.runs_summary("4.3", SCALE))
conds = ch4.conditions("4.3", settings["panels"])
runs = ch4.train_runs(settings, n_jobs=settings["n_jobs"])
wind = ch4.evaluate_runs(runs, "wind", settings["winds"], settings["test_rollouts"], n_jobs=settings["n_jobs"])

# %%
fig, axes = plot.lines_by_panel(
    wind,
    conds,
    "value",
    [("return", "testing return (reproduced)")],
    ch4.algo_names(settings),
    title=lambda cond, i: f"({cond['panel']}) {ch4.panel_title(cond)}",
    shade_wind=True,
    marker="o",
)
for ax in axes.flat:
    ax.set_xlabel("testing wind ξ")
fig.suptitle(
    f"Fig 4.3 reproduced — {settings['env']}, scale={SCALE}\n{plot.seed_band(wind, ['panel', 'algo', 'value'])}"
)
fig.tight_layout()
plot.save(fig, SCALE, "fig-4.3")

# %% [markdown]
# ## Does the claim reproduce at this scale?
# Mean testing return over the whole wind grid, per condition (reproduced): per training seed the mean over the
# grid and its rollouts, then mean ± half-width of the 95 % CI across training seeds (note under the table).

# %%
table = ch4.compare_ci(wind, "return")
print(table, table.attrs["note"], sep="\n")
_ = claims.judge_page(
    "fig-4.3", SCALE, {"wind": wind, "curves": ch4.curves_frame(runs)}, pages.claim_meta("4.3", settings)
)
