# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: percent
# ---

# %% [markdown]
# # Figure 5.6 — curriculum Reach → Throw → BIC vs no curriculum

# %% [markdown]
# The thesis's caption and claims open the book page (quoted with line numbers from
# `data/thesis/claims.yaml`, key `fig-5.6`); the verdicts at the end judge each claim on our numbers.
#
# What we run (`thesis_repro.arm.curriculum`), thesis cost (Eq 5.12) only, σ0 = 0.01 for every CMA-ES run
# (§5.3.2): the first family (Reach in CL; BIC's pre-training in NC) is constructive MTL from random policies —
# CMA-ES on the Tucker factors (G, U1, U2, U3) of all its tasks. Every later stage extracts the task-agnostic
# tensor L = G ×1 U1 ×2 U2 and alternates CMA-ES phases on the task vectors s ("fix L, update s") and on L
# ("fix s, update L"), as Algorithm 5 — the source of the "periodic bumps" of the thesis's curves. A new
# family's task starts from the s of a random task of the previous family (CL); NC's tasks keep their own.
# A trial is one CMA-ES candidate (one rollout per task). No numbers of this figure were transcribed (plot only).

# %% tags=["parameters"]
SCALE = "small"

# %%
import matplotlib.pyplot as plt
import seaborn as sns

from thesis_repro import claims, figures
from thesis_repro.book import pages
from thesis_repro.evaluation import tables
from thesis_repro.figures import ch5, plot

settings = figures.settings("5.6", SCALE)
print(pages.runs_summary("5.6", SCALE))
curves, final, pretraining = ch5.run_curriculum(settings, n_jobs=settings["n_jobs"])
pretraining.style.hide(axis="index").format(precision=3).set_caption(
    "Reproduced pre-training: cost (Eq 5.12) and population success at the end of each pre-training stage, per "
    "condition and seed (CL: Reach, then Throw; NC: its BIC pre-training)"
)

# %%
order = list(ch5.CONDITIONS)
band = plot.seed_band(curves, ["condition", "trials"])
fig, axes = plt.subplots(1, 2, figsize=(11, 4.1))
line = dict(x="trials", hue="condition", hue_order=order, errorbar=tables.t_errorbar)
sns.lineplot(data=curves, y="cost", ax=axes[0], **line)
axes[0].set(title="(a) reproduced: average cost on BIC", ylabel="mean cost of the population (Eq 5.12)")
sns.lineplot(data=curves, y="success", ax=axes[1], **line)
axes[1].set(title="(b) reproduced: success rate on BIC", ylabel="success rate of the population")
for ax in axes:
    ax.set_xlabel("BIC trials after pre-training")
    ax.title.set_fontsize(9)
fig.suptitle(band, fontsize=9)
fig.tight_layout()
plot.save(fig, SCALE, "fig-5.6", dpi=120)

# %% [markdown]
# ## Do the claims reproduce at this scale?
# Cost and success over the last 10 % of BIC trials (mean over seeds) and the final success of the learned
# policies (reproduced).

# %%
print(ch5.curriculum_end(curves).round(3))
_ = claims.judge_page("fig-5.6", SCALE, {"final": final, "curves": curves}, pages.claim_meta("5.6", settings))
