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

from stable_baselines3.common.vec_env import DummyVecEnv
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
