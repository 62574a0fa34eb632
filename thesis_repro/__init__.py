"""thesis_repro: reproduce, figure by figure, C. Zhao's thesis on generalisation in deep RL.

The package map, layers from the bottom up. A module imports only from its own layer and the layers below it
(``tests/test_layers.py`` reads this list and enforces it; ``tests/test_imports.py`` forbids import circles):

1. **core**: ``thesis_repro``, ``paths``, ``validation``, ``provenance``, ``scales``, ``thesis_numbers``,
   ``job_kinds``, ``bench``, ``terminal`` -- locations, checks, where and in which numerics an entry was made, the
   scale table, the thesis's numbers, the job registry, the timing helpers and output that fits the terminal; they
   import the standard library, third-party packages and each other only.
2. **store and backends**: ``cache``, ``backends`` -- the run cache and where jobs run; may import core (a job
   function is resolved by name through ``job_kinds``, never imported).
3. **envs**: ``envs`` -- the MuJoCo tasks and their perturbations; may import core.
4. **learners, mdl, arm**: ``learners``, ``mdl``, ``arm`` -- the RL learners, Alg 3's aggregation, chapter 5's
   arm; may import envs, the store (a job loads its dependencies through the run cache) and core.
5. **evaluation**: ``evaluation`` -- the chapter 3 testing protocol and its benchmark; may import every layer
   above this line.
6. **figures**: ``figures`` -- each item's jobs and numbers, no verdicts; may import every layer below.
7. **runs**: ``throughput``, ``plan``, ``runs``, ``shipped_checks``, ``retrain_check``, ``generator``, ``order``,
   ``study``, ``budget_study``, ``pilots``, ``budgets`` -- what a job costs, cost plans, where the runs are and their
   export into the shipped layer, the shipped layer's checks, a retrain against a shipped run, the reference-run
   generator and the order it makes items in (claims settled per core-hour), the protocol studies, the
   thesis-budget study, the pilot runs, budgets; may import figures and below.
8. **claims**: ``claims`` -- the claims ledger: judges the numbers the figures computed, in the verdict words
   of ``claims.report``; may import runs (the studies) and below, never figures.
9. **book and CLI**: ``book``, ``pages``, ``notebooks``, ``protocol``, ``agent``, ``clips``, ``verify``,
   ``__main__``, ``claims.__main__``, ``claims.cli`` -- pages, the book, a user's agent beside
   the shipped learners, videos of trained policies, ``make verify`` (it re-runs a claim's notebooks) and the
   command lines; may import everything.
"""

import os

# MuJoCo's offscreen renderer (MUJOCO_GL) is chosen where a task is made to render
# (thesis_repro.envs.make.prepare_render), never on import.

#: Portable numerics (issue 19 item 6): the same float kernels on every x86-64 CPU, so a run or an evaluation
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
