# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: percent
# ---

# %% [markdown]
# # Table 3.4 — Generalisation of the basic learners (AUC)
#
# The thesis's caption and claims open the book page (quoted with line numbers from
# `data/thesis/claims.yaml`, key `table-3.4`); the verdicts at the end judge each claim on our numbers.
#
# Cells: mean ± std of the testing AUC (Eq. 3.6) over training seeds × testing rollouts, **thesis** beside
# **reproduced**. Bold: the best learner of the row plus every learner not significantly different from it
# (two-sided Welch t-test, p < 0.05 as the captions say; `chapter3_settings.csv`). The thesis's bolding is not
# in its text: it is derived by the same rule from its mean ± std with n = 12 × 20 = 240 per cell. Grey cells
# (only where a scale skips a learner, `skip_algos`: under the thesis protocol no scale does, so every cell is run):
# not run at this scale. Logic: `thesis_repro.figures.ch3_tables`, statistics: `thesis_repro.evaluation.tables`.
#
# Under it, the reproduced cells across **training seeds**, the unit of replication (not the rollout): per seed the
# mean AUC over its testing rollouts, then the mean over seeds and its 95 % confidence interval (t-interval,
# n = seeds), shown as "mean [low, high] (seeds)"; with one seed there is no interval ("1 seed").

# %% tags=["parameters"]
SCALE = "small"

# %%
from thesis_repro import claims
from thesis_repro.book import pages
from thesis_repro.figures import ch3_tables
from thesis_repro.runs import budget_study

settings = ch3_tables.checked_settings("table-3.4", SCALE)
print(pages.runs_summary("table-3.4", SCALE))
print(ch3_tables.describe_budget(settings))
res = ch3_tables.run(settings, n_jobs=settings["n_jobs"])
comp = ch3_tables.compare("table-3.4", ch3_tables.our_cells(res), settings, ci=ch3_tables.our_ci(res))
comp.style("Table 3.4: testing AUC, thesis beside reproduced (bold: best or not significantly different)")

# %%
comp.ci_style("Table 3.4, reproduced: testing AUC across training seeds, mean [95 % CI] (seeds)")

# %% [markdown]
# ## Does the claim reproduce at this scale?

# %%
_ = claims.judge_page(
    "table-3.4",
    SCALE,
    ch3_tables.seed_frames(res),
    {**pages.claim_meta("table-3.4", settings), "thesis_budget": budget_study.page_meta("table-3.4", SCALE)},
    kit_checks=[claims.bolding_check("table-3.4", comp.agreement, SCALE)],
)
