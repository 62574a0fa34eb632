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
# **Thesis claims** (§3.3.2): "In this particular environment [Walker2d], SAC is usually the most robust
# algorithm. However overall, there is not a consistent winner in algorithm robustness across all environments
# as seen in Table 3.4. For example, PPO performs better in *InvertedPendulum* and *InvertedDoublePendulum*."
#
# > *Thesis caption:* Generalisation performance of basic Deep RL learners in terms of AUC scores. Algorithms are
# > trained on five standard deterministic environments, and tested with varying degrees of noise and
# > domain-shift. Results are averaged over 12 training seeds × 20 testing seeds. For each testing condition
# > (row), the results of the best-performing algorithm, as well as algorithms that are not significantly
# > different are highlighted in boldface. Welch's t-test with p < 0.05 is used for significance testing.
#
# Cells: mean ± std of the testing AUC (Eq. 3.6) over training seeds × testing rollouts, **thesis** beside
# **reproduced**. Bold: the best learner of the row plus every learner not significantly different from it
# (two-sided Welch t-test, p < 0.05 as the captions say; `chapter3_settings.csv`). The thesis's bolding is not
# in its text: it is derived by the same rule from its mean ± std with n = 12 × 20 = 240 per cell. Grey cells:
# not run at this scale. Logic: `thesis_repro.figures.ch3_tables`, statistics: `thesis_repro.evaluation.tables`.

# %% tags=["parameters"]
SCALE = "small"

# %%
from thesis_repro import figures, report
from thesis_repro.figures import ch3_tables

settings = ch3_tables.settings("table-3.4", SCALE)
print(figures.runs_summary("table-3.4", SCALE))
print(ch3_tables.describe(settings))
res = ch3_tables.run(settings, n_jobs=settings["n_jobs"])
comp = ch3_tables.compare("table-3.4", ch3_tables.our_cells(res), settings)
comp.style("Table 3.4: testing AUC, thesis beside reproduced (bold: best or not significantly different)")

# %% [markdown]
# ## Does the claim reproduce at this scale?

# %%
_ = report.report("table-3.4", SCALE, ch3_tables.table_verdicts("table-3.4", comp, settings))
