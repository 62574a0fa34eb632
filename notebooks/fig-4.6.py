# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: percent
# ---

# %% [markdown]
# # Figure 4.6 — Testing return vs observation-noise and action-noise scale

# %% [markdown]
# The thesis's caption and claims open the book page (quoted with line numbers from
# `data/thesis/claims.yaml`, key `fig-4.6`); the verdicts at the end judge each claim on our numbers.
#
# Policies: the cached runs of Fig 4.1 (wind off at test); σ grid: the scale table's `sigmas`. Each curve
# is summarised by its AUC (Eq 3.6). All numbers are **reproduced**.
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
import pandas as pd

from thesis_repro import claims, figures
from thesis_repro.book import pages
from thesis_repro.figures import ch4, plot

settings = figures.settings("4.6", SCALE)
print(pages.runs_summary("4.6", SCALE))
conds = ch4.conditions("4.6", settings["panels"])
runs = ch4.train_runs(settings, n_jobs=settings["n_jobs"])
noise = pd.concat(
    [
        ch4.evaluate_runs(runs, kind, settings["sigmas"], settings["test_rollouts"], n_jobs=settings["n_jobs"]).assign(
            noise=kind
        )
        for kind in ("obs", "act")
    ]
)

# %%
wide = noise.pivot_table(index=["panel", "algo", "seed", "value"], columns="noise", values="return").reset_index()
fig, axes = plot.lines_by_panel(
    wide,
    conds,
    "value",
    [("obs", "testing return, obs noise (reproduced)"), ("act", "testing return, act noise (reproduced)")],
    ch4.algo_names(settings),
    title=lambda cond, i: f"({cond['panel']}) {ch4.panel_title(cond)}" if i == 0 else "",
    marker="o",
)
for ax in axes.flat:
    ax.set_xlabel("noise scale σ")
fig.suptitle(
    f"Fig 4.6 reproduced — {settings['env']}, scale={SCALE}\n{plot.seed_band(wide, ['panel', 'algo', 'value'])}"
)
fig.tight_layout()
plot.save(fig, SCALE, "fig-4.6")

# %% [markdown]
# ## Does the claim reproduce at this scale?
# AUC (Eq 3.6) of the mean return over σ, per noise type and condition (reproduced): per training seed the AUC of
# its own curve, then mean ± half-width of the 95 % CI across training seeds (note under the table; the mean equals
# the AUC of the seed-mean curve, as the AUC is linear in the returns).

# %%
aucs = ch4.noise_aucs(noise, per_seed=True)
aucs = ch4.compare_ci(aucs, "auc", by=("noise", "panel"), algos=ch4.algo_names(settings))
print(aucs, aucs.attrs["note"], sep="\n")
_ = claims.judge_page(
    "fig-4.6", SCALE, {"noise": noise, "curves": ch4.curves_frame(runs)}, pages.claim_meta("4.6", settings)
)
