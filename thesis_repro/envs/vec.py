"""``LeanVecEnv``: SB3's ``DummyVecEnv`` without its per-step deep copies (same observations, rewards, dones, infos).

``DummyVecEnv.step_wait`` deep-copies the observation buffer and every info dict on every step (~15 % of
a Hopper training step). The kit's envs return fresh info dicts and observation arrays from every
``step``/``reset``, so :class:`LeanVecEnv` returns a copy of the observation buffer and a shallow copy of
each info dict instead; everything else (auto-reset, ``terminal_observation``, ``TimeLimit.truncated``,
seeding, ``reset_infos``, the VecEnv interface that ``VecMonitor``/``VecNormalize`` wrap) is
``DummyVecEnv``'s own code. Only flat (non-dict) observation spaces take the lean path.

>>> import numpy as np
>>> from thesis_repro.envs import make_env
>>> venv = LeanVecEnv([lambda: make_env("Hopper", seed=0)])
>>> obs = venv.reset(); obs2, rew, done, infos = venv.step(np.zeros((1, 3)))
>>> obs2.shape, sorted(infos[0])[:2]
((1, 11), ['TimeLimit.truncated', 'reward_ctrl'])
"""

from __future__ import annotations

import numpy as np
from stable_baselines3.common.running_mean_std import RunningMeanStd
from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize
from stable_baselines3.common.vec_env.base_vec_env import VecEnvObs, VecEnvStepReturn


class LeanVecEnv(DummyVecEnv):
    """``DummyVecEnv`` with copy-free ``step_wait`` (see module docstring)."""

    def step_wait(self) -> VecEnvStepReturn:
        if self.keys != [None]:
            return super().step_wait()
        buf_obs, rews, dones, infos = self.buf_obs[None], self.buf_rews, self.buf_dones, self.buf_infos
        for i, env in enumerate(self.envs):
            obs, rews[i], terminated, truncated, info = env.step(self.actions[i])
            done = terminated or truncated
            dones[i] = done
            info = dict(info)
            info["TimeLimit.truncated"] = truncated and not terminated
            if done:
                info["terminal_observation"] = obs
                obs, self.reset_infos[i] = env.reset()
            infos[i] = info
            buf_obs[i] = obs
        return buf_obs.copy(), rews.copy(), dones.copy(), list(infos)

    def _obs_from_buf(self) -> VecEnvObs:
        if self.keys != [None]:
            return super()._obs_from_buf()
        return self.buf_obs[None].copy()


class LeanVecNormalize(VecNormalize):
    """``VecNormalize`` with the same statistics and outputs, minus per-step copies: ``normalize_obs`` skips the
    deep copy it overwrites anyway, ``get_original_obs`` copies the raw array instead of deep-copying it, and a
    one-env batch updates the running mean/variance from its moments directly (mean = the row, variance = 0,
    exactly what ``np.mean``/``np.var`` give for one row). Pickles and loads like ``VecNormalize``.

    >>> import numpy as np
    >>> from thesis_repro.envs import make_env
    >>> venv = LeanVecNormalize(LeanVecEnv([lambda: make_env("Hopper", seed=0)]))
    >>> venv.reset().dtype, venv.step(np.zeros((1, 3)))[0].shape
    (dtype('float32'), (1, 11))
    """

    @staticmethod
    def _update(rms: RunningMeanStd, arr: np.ndarray) -> None:
        if arr.shape[0] == 1:
            rms.update_from_moments(arr[0], np.zeros_like(arr[0]), 1)
        else:
            rms.update(arr)

    def step_wait(self) -> VecEnvStepReturn:
        if not isinstance(self.obs_rms, RunningMeanStd):  # dict observations: VecNormalize's own code
            return super().step_wait()
        obs, rewards, dones, infos = self.venv.step_wait()
        self.old_obs, self.old_reward = obs, rewards
        if self.training and self.norm_obs:
            self._update(self.obs_rms, obs)
        obs = self.normalize_obs(obs)
        if self.training:
            self.returns = self.returns * self.gamma + rewards
            self._update(self.ret_rms, self.returns)
        rewards = self.normalize_reward(rewards)
        for idx, done in enumerate(dones):
            if done and "terminal_observation" in infos[idx]:
                infos[idx]["terminal_observation"] = self.normalize_obs(infos[idx]["terminal_observation"])
        self.returns[dones] = 0
        return obs, rewards, dones, infos

    def normalize_obs(self, obs: np.ndarray | dict[str, np.ndarray]) -> np.ndarray | dict[str, np.ndarray]:
        if self.norm_obs and isinstance(obs, np.ndarray) and isinstance(self.obs_rms, RunningMeanStd):
            return self._normalize_obs(obs, self.obs_rms).astype(np.float32)
        return super().normalize_obs(obs)

    def get_original_obs(self) -> np.ndarray | dict[str, np.ndarray]:
        if isinstance(self.old_obs, np.ndarray):
            return self.old_obs.copy()
        return super().get_original_obs()
