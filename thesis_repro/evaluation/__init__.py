"""Chapter-3 evaluation protocol (thesis §3.2.2, Eq. 3.3, 3.4, 3.6): metrics, batched evaluator, jobs, scoring.

Result arrays use the axis order ``(training seeds, tasks, algorithms, sigmas, testing rollouts)``.

>>> from thesis_repro.evaluation import auc
>>> auc([100.0, 80.0, 40.0], [0.0, 0.2, 0.4])
44.0
"""

from thesis_repro.evaluation.evaluator import (
    PERTURBATIONS,
    BatchedEvaluator,
    Rollouts,
    evaluate,
    evaluate_shift,
    gym_make,
    test_seeds,
)
from thesis_repro.evaluation.jobs import (
    Benchmark,
    BenchmarkResult,
    benchmark_jobs,
    check_test,
    evaluate_job,
)
from thesis_repro.evaluation.metrics import auc, correlation, expected_return, pareto_frontier, sigma_step
from thesis_repro.evaluation.score import Scores, book_grid, default_sigmas, sb3_policy, score_model, summarise

__all__ = [
    "PERTURBATIONS",
    "BatchedEvaluator",
    "Benchmark",
    "BenchmarkResult",
    "Rollouts",
    "Scores",
    "auc",
    "benchmark_jobs",
    "book_grid",
    "check_test",
    "correlation",
    "default_sigmas",
    "evaluate",
    "evaluate_job",
    "evaluate_shift",
    "expected_return",
    "gym_make",
    "pareto_frontier",
    "sb3_policy",
    "score_model",
    "sigma_step",
    "summarise",
    "test_seeds",
]
