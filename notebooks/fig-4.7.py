# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: percent
# ---

# %% [markdown]
# # Figure 4.7 — Policy entropy during training: kl_avg vs params_avg vs joint
#
# Thesis claim (§4.3.4, Walker2d, c_a = 0.1, ξ ~ U(−0.5, 0.5)): averaging the sub-policies in the space
# of action distributions keeps the policy entropy higher (the entropy only decreases when the domains'
# updates agree), a soft entropy regularisation. The entropy is that of the diagonal-Gaussian policy
# (state-independent log-std) after each iteration; the numbers are **reproduced**.

# %% tags=["parameters"]
SCALE = "small"

# %%
import matplotlib.pyplot as plt
import seaborn as sns

from thesis_repro import paths
from thesis_repro.mdl import experiments as ex
from thesis_repro.scales import figure_settings

settings = figure_settings("4.7", SCALE)
conds = ex.conditions("4.7", settings["panels"])
runs = ex.train_runs(settings, settings["algos"], conds, n_jobs=settings["n_jobs"])
curves = ex.curves_frame(runs)
curves["source"] = "reproduced"

# %%
fig, axes = plt.subplots(1, 2, figsize=(10, 3.8))
sns.lineplot(
    data=curves, x="iteration", y="entropy", hue="algo", hue_order=settings["algos"], errorbar="sd", ax=axes[0]
)
axes[0].set_ylabel("policy entropy [nats] (reproduced)")
axes[0].set_title(f"{ex.label(conds[0])}")
kl = curves.dropna(subset=["kl_to_aggregate"])
sns.lineplot(data=kl, x="iteration", y="kl_to_aggregate", hue="algo", ax=axes[1])
axes[1].set_yscale("log")
axes[1].set_ylabel("mean KL(sub-policy ‖ aggregate)")
fig.suptitle(f"Fig 4.7 reproduced — {settings['env']}, scale={SCALE}")
fig.tight_layout()
out = paths.figures(SCALE) / "fig-4.7.png"
fig.savefig(out, dpi=100)
print("saved", out)

# %% [markdown]
# ## Does the claim hold at this scale?

# %%
final = curves[curves["iteration"] == curves["iteration"].max()]
table = ex.compare(final, "entropy")
print(table)
lines, holds = ex.verdict(table, easy=(), what="final entropy")
print("\n".join(lines))
print(
    f"Conclusion (reproduced, scale={SCALE}): kl_avg keeping the highest policy entropy "
    f"{'HOLDS' if holds else 'does NOT hold'} here."
)
print(ex.caveat(settings))
