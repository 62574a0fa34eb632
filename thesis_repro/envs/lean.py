"""Hopper-v5 and Walker2d-v5 with a leaner ``step``: the same transitions, rewards and infos as Gymnasium's.

Gymnasium's ``step`` of these two tasks evaluates the ``is_healthy`` property twice per step (once in the
reward, once for termination; ~40 % of the Python time of a Hopper step). :class:`LeanHopper` and
:class:`LeanWalker2d` compute it once, with a cheaper but identical test, and build the same ``info``.
Everything else (simulation, observation, reset, rendering, ``spec``) is Gymnasium's own code.
:func:`lean_spec` is the registered spec with the lean class as entry point and no order-enforcing
wrapper; :func:`thesis_repro.envs.make_env` builds every task from it. ``tests/test_fast.py`` checks
that N steps (with resets and every perturbation) give identical observations, rewards, flags and infos.

>>> import gymnasium as gym
>>> env = gym.make(lean_spec("Hopper-v5"))
>>> type(env.unwrapped).__name__, env.unwrapped.spec.id
('LeanHopper', 'Hopper-v5')
"""

from __future__ import annotations

import dataclasses

import gymnasium as gym
import numpy as np
from gymnasium.envs.mujoco.hopper_v5 import HopperEnv
from gymnasium.envs.mujoco.walker2d_v5 import Walker2dEnv
from numpy._core.umath import clip as _clip  # what np.clip(float array, lo, hi) calls

_add_reduce = np.add.reduce  # what np.sum(ndarray) calls


class _LeanLocomotion:
    """``step`` of Hopper/Walker2d v5 with one health evaluation (needs ``is_healthy``), and Gymnasium's
    ``_get_obs``, ``control_cost`` and ``do_simulation`` with the same numpy kernels called directly (the
    ``clip`` and ``add.reduce`` ufuncs that ``np.clip``/``np.sum`` dispatch to) and no copy of the action."""

    def do_simulation(self, ctrl, n_frames) -> None:
        if np.shape(ctrl) != (self.model.nu,):  # MujocoEnv's check, without np.array's copy of the action
            raise ValueError(f"Action dimension mismatch. Expected {(self.model.nu,)}, found {np.shape(ctrl)}")
        self._step_mujoco_simulation(ctrl, n_frames)

    def _get_obs(self):
        data = self.data
        position = data.qpos[1:] if self._exclude_current_positions_from_observation else data.qpos
        return np.concatenate((position, _clip(data.qvel, -10, 10)))  # = concatenate((qpos, clip(qvel))).ravel()

    def control_cost(self, action):
        return self._ctrl_cost_weight * _add_reduce(np.square(action), axis=None)  # = np.sum(np.square(action))

    def step(self, action):
        data = self.data
        x_position_before = data.qpos[0]
        self.do_simulation(action, self.frame_skip)
        x_position_after = data.qpos[0]
        x_velocity = (x_position_after - x_position_before) / self.dt

        observation = self._get_obs()
        healthy = self.is_healthy
        forward_reward = self._forward_reward_weight * x_velocity
        healthy_reward = healthy * self._healthy_reward
        rewards = forward_reward + healthy_reward
        ctrl_cost = self.control_cost(action)
        reward = rewards - ctrl_cost
        terminated = (not healthy) and self._terminate_when_unhealthy
        info = {
            "x_position": x_position_after,
            "z_distance_from_origin": data.qpos[1] - self.init_qpos[1],
            "x_velocity": x_velocity,
            "reward_forward": forward_reward,
            "reward_ctrl": -ctrl_cost,
            "reward_survive": healthy_reward,
        }
        if self.render_mode == "human":
            self.render()
        return observation, reward, terminated, False, info


class LeanHopper(_LeanLocomotion, HopperEnv):
    """Gymnasium's ``HopperEnv`` (v5) with a leaner, identical ``step`` and ``is_healthy``."""

    @property
    def is_healthy(self) -> bool:
        qpos = self.data.qpos
        min_z, max_z = self._healthy_z_range
        min_angle, max_angle = self._healthy_angle_range
        if not (min_z < qpos[1] < max_z and min_angle < qpos[2] < max_angle):
            return False
        min_state, max_state = self._healthy_state_range
        state = np.concatenate((qpos[2:], self.data.qvel))  # = state_vector()[2:]
        return bool(((min_state < state) & (state < max_state)).all())


class LeanWalker2d(_LeanLocomotion, Walker2dEnv):
    """Gymnasium's ``Walker2dEnv`` (v5) with a leaner, identical ``step`` and ``is_healthy``."""

    @property
    def is_healthy(self) -> np.bool_:
        qpos = self.data.qpos
        min_z, max_z = self._healthy_z_range
        min_angle, max_angle = self._healthy_angle_range
        return min_z < qpos[1] < max_z and min_angle < qpos[2] < max_angle  # np.bool_, as Gymnasium's


LEAN: dict[str, type] = {"Hopper-v5": LeanHopper, "Walker2d-v5": LeanWalker2d}


def lean_spec(env_id: str) -> gym.envs.registration.EnvSpec | str:
    """The registered spec of ``env_id`` with its lean class (if any) and without the order-enforcing wrapper."""
    spec = gym.spec(env_id)
    cls = LEAN.get(env_id)
    entry = f"{cls.__module__}:{cls.__qualname__}" if cls is not None else spec.entry_point
    return dataclasses.replace(spec, entry_point=entry, order_enforce=False)
