"""thesis_repro: reproduce, figure by figure, C. Zhao's thesis on generalisation in deep RL.

The package map, layers from the bottom up, one folder each. A module imports only from its own layer and the
layers below it (``tests/test_layers.py`` reads this list and enforces it; ``tests/test_imports.py`` forbids import
circles):

1. **core**: ``thesis_repro``, ``core`` -- locations, argument checks, where and in which numerics an entry was
   made, the scale table, the thesis's numbers, the job registry, code stamps, timing helpers, output that fits
   the terminal, the run cache and where jobs run (a job function is resolved by name through
   ``core.job_kinds``, never imported).
2. **envs**: ``envs`` -- the MuJoCo tasks and their perturbations.
3. **learners, mdl, arm**: ``learners``, ``mdl``, ``arm`` -- the RL learners, Alg 3's aggregation, chapter 5's
   arm (a job loads its dependencies through the run cache).
4. **evaluation**: ``evaluation`` -- the chapter 3 testing protocol and its benchmark.
5. **figures**: ``figures`` -- each item's jobs and numbers, no verdicts.
6. **runs**: ``runs`` -- which jobs a figure needs (``runs.needs``, pure), what they cost, where the runs are and
   their export into the shipped layer, its checks, a retrain against a shipped run, the reference-run generator
   and its order, the protocol studies, the thesis-budget study, the pilots, budgets.
7. **claims**: ``claims`` -- the claims ledger: judges the numbers the figures computed, in the verdict words of
   ``claims.report``; never imports figures.
8. **book**: ``book`` -- pages, notebook execution, the book's build, the protocol table, videos of trained
   policies and a user's agent beside the shipped learners.
9. **command line**: ``cli``, ``__main__``, ``claims.__main__``, ``claims.cli`` -- ``python -m thesis_repro``,
   ``make verify`` (it re-runs a claim's notebooks) and the claims command line.
"""

import os

# MuJoCo's offscreen renderer (MUJOCO_GL) is chosen where a task is made to render
# (thesis_repro.envs.make.prepare_render), never on import.

#: Portable numerics: the same float kernels on every x86-64 CPU, so a run or an evaluation
#: gives the same numbers on Intel and AMD. Measured on an AVX-512 Xeon: MKL's CPU dispatch (the sgemm of every
#: policy forward and PPO update) changes an evaluation's returns in the 7th digit and a training run's weights;
#: MKL's COMPATIBLE branch is the only one its documentation promises identical on Intel and compatible
#: processors ("Settings other than AUTO or COMPATIBLE are available only for Intel processors"). ATen's own
#: kernels (tanh, exp, ...) dispatch on AVX-512 vs AVX2: pinned to AVX2, which every x86-64-v3 CPU has.
#: Cost (measured 2026-11-25, README): 9-27 % of training throughput by learner. Must be set before torch loads
#: MKL: ``import thesis_repro`` first (the Makefile exports them too); :func:`numerics` reports what is in effect
#: (kept in every entry's provenance).
#: ``THESIS_REPRO_NUMERICS=native`` leaves them unset (how the earliest shipped runs were trained: ``make verify``
#: and the retrain test recompute an entry in the numerics its provenance records).
PORTABLE_NUMERICS = {"MKL_CBWR": "COMPATIBLE", "ATEN_CPU_CAPABILITY": "avx2"}
NUMERICS_ENV = "THESIS_REPRO_NUMERICS"
if os.environ.get(NUMERICS_ENV, "portable") != "native":
    for _name, _value in PORTABLE_NUMERICS.items():
        os.environ.setdefault(_name, _value)


def numerics() -> dict[str, str | None]:
    """The numerics settings in effect in this process: the pinned variables and torch's CPU capability.

    >>> numerics()["MKL_CBWR"]
    'COMPATIBLE'
    """
    import torch  # local: the numerics variables above must be set before torch loads MKL

    return {
        **{k: os.environ.get(k) for k in PORTABLE_NUMERICS},
        "torch_cpu_capability": torch.backends.cpu.get_cpu_capability(),
    }


__version__ = "0.1.0"
