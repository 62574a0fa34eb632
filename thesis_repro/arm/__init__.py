"""Chapter 5: the 2-D arm dynamic tasks, the DMP-inspired RBF-PD policy and their learning.

>>> from thesis_repro.arm import FAMILIES, RBFPolicy, simulate
>>> FAMILIES
('reach', 'throw', 'bic', 'cast')
"""

from thesis_repro.arm.policy import RBFPolicy
from thesis_repro.arm.tasks import (
    FAMILIES,
    SIM_VERSION,
    TASK_PARAM_NAMES,
    TASK_RANGES,
    ArmConfig,
    Rollout,
    check_family,
    sample_tasks,
    simulate,
    validate_tasks,
)

__all__ = [
    "FAMILIES",
    "SIM_VERSION",
    "TASK_PARAM_NAMES",
    "TASK_RANGES",
    "ArmConfig",
    "RBFPolicy",
    "Rollout",
    "check_family",
    "sample_tasks",
    "simulate",
    "validate_tasks",
]
