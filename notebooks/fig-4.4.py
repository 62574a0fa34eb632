# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: percent
# ---

# %% [markdown]
# # Figure 4.4 — Hopper: testing return vs wind (a) and over body-mass × friction ratios (b)

# %% [markdown]
# The thesis's caption and claims open the book page (quoted with line numbers from
# `data/thesis/claims.yaml`, key `fig-4.4`); the verdicts at the end judge each claim on our numbers.
#
# All numbers are **reproduced**.
#
# Learners: the thesis's kl_avg (Alg 3 with Eq 4.11), kl_exact (ours: the exact minimiser of Eq 4.7
# from params_avg), params_avg (Eq 4.6) and joint (PPO on the merged batch). Each claim is judged twice, for
# kl_avg and for kl_exact (counted beyond the thesis), each against params_avg and joint only (`claims.yaml`).
#
# (a) Lines: the mean over training seeds of each seed's mean testing return over its rollouts; band: the 95 %
# confidence interval of that mean across training seeds (t-interval, n = seeds; none with one seed), as the figure
# title says. (b) Cells: the mean over training seeds of each seed's mean testing return over its rollouts; the
# figure title says over how many seeds (no interval in the cells: see the table below).

# %% tags=["parameters"]
SCALE = "small"

# %%
import seaborn as sns

from thesis_repro import claims, figures
from thesis_repro.book import pages
from thesis_repro.evaluation import tables
from thesis_repro.figures import ch4, plot

settings = figures.settings("4.4", SCALE)
print(pages.runs_summary("4.4", SCALE))
(cond,) = ch4.conditions("4.4", settings["panels"])
runs = ch4.train_runs(settings, n_jobs=settings["n_jobs"])
wind = ch4.evaluate_runs(runs, "wind", settings["winds"], settings["test_rollouts"], n_jobs=settings["n_jobs"])
grid = ch4.mass_friction_grid(settings)
heat = ch4.evaluate_runs(runs, "shift", grid, settings["test_rollouts"], n_jobs=settings["n_jobs"])

# %%
algos = ch4.algo_names(settings)
fig, axes = plot.panel_grid(1 + len(algos))
sns.lineplot(
    data=wind, x="value", y="return", hue="algo", hue_order=algos, marker="o", errorbar=tables.t_errorbar, ax=axes[0]
)
axes[0].axvspan(*cond["wind"], color="grey", alpha=0.15)
axes[0].set(title=f"(a) {ch4.panel_title(cond)}", xlabel="testing wind ξ", ylabel="testing return (reproduced)")
vmin, vmax = heat["return"].min(), heat["return"].max()
for i, algo in enumerate(algos):
    sub = heat[heat["algo"] == algo]
    plot.heatmap(axes[1 + i], sub, f"(b) {algo} (reproduced)", vmin=vmin, vmax=vmax, cbar=(i == len(algos) - 1))
band, cells = plot.seed_band(wind, ["algo", "value"]), plot.seed_cells(heat, ["algo", "mass", "friction"])
fig.suptitle(f"Fig 4.4 reproduced — {settings['env']}, scale={SCALE}\n(a) {band}\n(b) {cells}")
fig.tight_layout()
plot.save(fig, SCALE, "fig-4.4")

# %% [markdown]
# ## Does the claim reproduce at this scale?
# (a) mean testing return over the wind grid; (b) mean over the off-centre cells (all but mass = friction = 1).
# Per training seed the mean over the grid and its rollouts, then mean ± half-width of the 95 % CI across training
# seeds (note under each table).

# %%
wind_table = ch4.compare_ci(wind, "return", by=("condition",))
print("(a) wind", wind_table.to_string(), wind_table.attrs["note"], sep="\n", end="\n\n")
heat_table = ch4.compare_ci(ch4.off_centre(heat), "return", by=("condition",))
print("(b) off-centre", heat_table.to_string(), heat_table.attrs["note"], sep="\n")
_ = claims.judge_page(
    "fig-4.4",
    SCALE,
    {"wind": wind, "heat": heat, "curves": ch4.curves_frame(runs)},
    pages.claim_meta("4.4", settings),
)
