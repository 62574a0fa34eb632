# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: percent
# ---

# %% [markdown]
# # Figure 4.5 — Walker2d testing return over body-mass × friction ratios (heat maps)

# %% [markdown]
# The thesis's caption and claims open the book page (quoted with line numbers from
# `data/thesis/claims.yaml`, key `fig-4.5`); the verdicts at the end judge each claim on our numbers.
#
# Policies: the cached runs of Fig 4.1 (wind off at test). All numbers are **reproduced**.
#
# Learners: the thesis's kl_avg (Alg 3 with Eq 4.11), kl_exact (ours: the exact minimiser of Eq 4.7
# from params_avg), params_avg (Eq 4.6) and joint (PPO on the merged batch). Each claim is judged twice, for
# kl_avg and for kl_exact (counted beyond the thesis), each against params_avg and joint only (`claims.yaml`).
#
# Cells: the mean over training seeds of each seed's mean testing return over its rollouts; the figure title says
# over how many seeds (no interval in the cells: the table below gives mean ± 95 % CI across seeds).

# %% tags=["parameters"]
SCALE = "small"

# %%
import matplotlib.pyplot as plt

from thesis_repro import claims, figures
from thesis_repro.book import pages
from thesis_repro.figures import ch4, plot

settings = figures.settings("4.5", SCALE)
print(pages.runs_summary("4.5", SCALE))
conds = ch4.conditions("4.5", settings["panels"])
runs = ch4.train_runs(settings, n_jobs=settings["n_jobs"])
grid = ch4.mass_friction_grid(settings)
heat = ch4.evaluate_runs(runs, "shift", grid, settings["test_rollouts"], n_jobs=settings["n_jobs"])

# %%
algos = ch4.algo_names(settings)
fig, axes = plt.subplots(len(algos), len(conds), figsize=(3.2 * len(conds), 2.8 * len(algos)), squeeze=False)
for j, cond in enumerate(conds):
    col = heat[heat["panel"] == cond["panel"]]  # one colour scale per training condition (column)
    for i, algo in enumerate(algos):
        title = f"{algo} ({cond['panel']}), reproduced"
        plot.heatmap(axes[i, j], col[col["algo"] == algo], title, vmin=col["return"].min(), vmax=col["return"].max())
cells = plot.seed_cells(heat, ["panel", "algo", "mass", "friction"])
fig.suptitle(f"Fig 4.5 reproduced — {settings['env']}, scale={SCALE}\n{cells}")
fig.tight_layout()
plot.save(fig, SCALE, "fig-4.5")

# %% [markdown]
# ## Does the claim reproduce at this scale?
# Mean testing return over the off-centre cells (every cell except mass = friction = 1), per condition: per training
# seed the mean over those cells and its rollouts, then mean ± half-width of the 95 % CI across training seeds (note
# under the table).

# %%
table = ch4.compare_ci(ch4.off_centre(heat), "return")
print(table, table.attrs["note"], sep="\n")
_ = claims.judge_page(
    "fig-4.5", SCALE, {"heat": heat, "curves": ch4.curves_frame(runs)}, pages.claim_meta("4.5", settings)
)
