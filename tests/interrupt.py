"""A simulated interruption for training tests: an SB3 callback that raises ``KeyboardInterrupt`` at a step."""

from __future__ import annotations

from stable_baselines3.common.callbacks import BaseCallback


class Interrupt(BaseCallback):
    """Raise ``KeyboardInterrupt`` once the run has done ``at`` env steps (as Ctrl-C would, mid-iteration)."""

    def __init__(self, at: int):
        super().__init__()
        self.at = at

    def _on_step(self) -> bool:
        if self.num_timesteps >= self.at:
            raise KeyboardInterrupt("simulated interruption")
        return True
