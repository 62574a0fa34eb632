# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: percent
# ---

# %% [markdown]
# # Table 3.5 — Training with noisy and multiple environments (AUC)
#
# **Thesis claims** (§3.3.3): "Overall the results show positive improved generalisation when training with
# noisy environments. Interestingly, there is some transferability across noise types. MDL training often
# improves robustness not only to novel domains at testing, but also i.i.d observation, action, and environment
# noise. Meanwhile, observation noise training improves robustness to action noise and MDL testing in
# *HalfCheetah*."
#
# > *Thesis caption:* Generalisation performance of training with noisy and multiple environments in terms of AUC
# > score. [...] For all noisy training settings, gaussian noise with 0.2 standard deviation is used during
# > training. All performance are averaged over 12 training seeds × 20 testing seeds. Results of the
# > best-performing training setting on each testing condition, as well as the ones that are not significantly
# > different, are highlighted in boldface. Welch's t-test with p < 0.05 is used for significant testing.
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

settings = ch3_tables.settings("table-3.5", SCALE)
print(figures.runs_summary("table-3.5", SCALE))
print(ch3_tables.describe(settings))
res = ch3_tables.run(settings, n_jobs=settings["n_jobs"])
comp = ch3_tables.compare("table-3.5", ch3_tables.our_cells(res), settings)
comp.style("Table 3.5: testing AUC, thesis beside reproduced (bold: best or not significantly different)")

# %% [markdown]
# ## Does the claim reproduce at this scale?

# %%
_ = report.report("table-3.5", SCALE, ch3_tables.table_verdicts("table-3.5", comp, settings))
