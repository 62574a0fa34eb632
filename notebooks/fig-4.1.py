# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: percent
# ---

# %% [markdown]
# # Figure 4.1 — Training curves of kl_avg, kl_exact, params_avg and joint under four conditions

# %% [markdown]
# The thesis's caption and claims open the book page (quoted with line numbers from
# `data/thesis/claims.yaml`, key `fig-4.1`); the verdicts at the end judge each claim on our numbers.
#
# kl_avg is Alg 3 (Fisher-weighted aggregation, Eq 4.11), params_avg Eq 4.6, joint one PPO on the merged
# batch. The conditions come from `data/thesis/chapter4_conditions.csv`; the curves are **reproduced**
# (the thesis gives only plots). Logic: `thesis_repro.figures.ch4`.
#
# Learners: the thesis's kl_avg (Alg 3 with Eq 4.11), kl_exact (ours: the exact minimiser of Eq 4.7
# from params_avg), params_avg (Eq 4.6) and joint (PPO on the merged batch). Each claim is judged twice, for
# kl_avg and for kl_exact (counted beyond the thesis), each against params_avg and joint only (`claims.yaml`).
#
# Lines: the mean over training seeds; band: the 95 % confidence interval of that mean across training seeds
# (t-interval, n = seeds; none with one seed), as the figure title says.

# %% tags=["parameters"]
SCALE = "small"

# %%
from thesis_repro import claims, figures
from thesis_repro.book import pages
from thesis_repro.claims import readings
from thesis_repro.figures import ch4, plot

settings = figures.settings("4.1", SCALE)
print(pages.runs_summary("4.1", SCALE))
conds = ch4.conditions("4.1", settings["panels"])
curves = ch4.curves_frame(ch4.train_runs(settings, n_jobs=settings["n_jobs"]))
last = curves.groupby(["panel", "algo", "seed"])[["return", "length"]].last()
last.style.format(precision=1).set_caption(
    "Reproduced: training return and episode length at the last iteration, per panel, learner and training seed"
)

# %%
fig, axes = plot.lines_by_panel(
    curves,
    conds,
    "iteration",
    [("return", "episode return (reproduced)"), ("length", "episode length (reproduced)")],
    ch4.algo_names(settings),
    title=lambda cond, i: f"({cond['panel']}) {ch4.panel_title(cond)}" if i == 0 else "",
)
band = plot.seed_band(curves, ["panel", "algo", "iteration"])
fig.suptitle(f"Fig 4.1 reproduced — {settings['env']}, scale={SCALE}, {settings['train_seeds']} seed(s)\n{band}")
fig.tight_layout()
plot.save(fig, SCALE, "fig-4.1")

# %% [markdown]
# ## Does the claim reproduce at this scale?
# Mean training return over the last third of the iterations, per condition (reproduced): per training seed the
# mean over its late iterations, then mean ± half-width of the 95 % CI across training seeds (note under the table).

# %%
late = ch4.late_returns_ci(curves)
print(late, late.attrs["note"], sep="\n")
print("\nTraining runs that diverged (late return below half its peak; no claim reads them), of the seeds run:")
print(readings.diverged_table(curves))
print("\nSub-policies' drift from the aggregate: largest mean KL to it over training, median over seeds (max):")
print(ch4.aggregate_kl(curves).to_string())
_ = claims.judge_page("fig-4.1", SCALE, {"curves": curves}, pages.claim_meta("4.1", settings))
