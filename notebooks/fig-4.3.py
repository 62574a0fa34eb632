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
# **Thesis claim** (§4.3.3): evaluated with wind speeds ξ ∈ [−5, 5] (wider than in training), "the proposed
# method kl_avg is observed to generalise to a wider range of domain": competitive in the easiest condition,
# more robust than params_avg and joint when training is harder.
#
# > *Thesis caption:* Testing performance of learned policies under different wind conditions in *Walker*
# > task. The proposed method *kl_avg* is observed to generalise to a wider range of domain. Four training
# > conditions are (a): c_a = 0.001, ξ ~ U(−0.5, 0.5), (b): c_a = 0.001, ξ ~ U(−2.5, 2.5), (c): c_a = 1.0,
# > ξ ~ U(−0.5, 0.5), (d): c_a = 1.0, ξ ~ U(−2.5, 2.5). Results are averaged over 6 random seeds.
#
# The policies are the cached runs of Fig 4.1; each is tested with its mean action over `test_rollouts`
# testing seeds per wind speed. All numbers are **reproduced** (the thesis gives only plots).

# %% tags=["parameters"]
SCALE = "small"

# %%
from thesis_repro import figures, report
from thesis_repro.figures import ch4, plot

settings = figures.settings("4.3", SCALE)
print(figures.runs_summary("4.3", SCALE))
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
    title=lambda cond, i: f"({cond['panel']}) {ch4.label(cond)}",
    shade_wind=True,
    marker="o",
)
for ax in axes.flat:
    ax.set_xlabel("testing wind ξ")
fig.suptitle(f"Fig 4.3 reproduced — {settings['env']}, scale={SCALE}")
fig.tight_layout()
plot.save(fig, SCALE, "fig-4.3")

# %% [markdown]
# ## Does the claim reproduce at this scale?
# Mean testing return over the whole wind grid, per condition (reproduced).

# %%
print(ch4.compare(wind, "return"))
_ = report.report("fig-4.3", SCALE, ch4.verdict_4_3(wind, settings))
