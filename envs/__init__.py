"""Gymnasium environments ETB-1A-v0 .. ETB-3C-v0 (one per model of Table 3 of the paper).

    import gymnasium as gym
    import etb_gym                                   # registers the nine ids
    env = gym.make("ETB-3B-v0", render_mode="rgb_array")
    obs, info = env.reset(seed=0)
    obs, reward, terminated, truncated, info = env.step(env.action_space.sample())

``gym.make("etb_gym:ETB-3B-v0")`` works without importing etb_gym first, and
``gym.make_vec("ETB-3B-v0", num_envs=64)`` builds the native batched vector env (:mod:`.vector`).
See docs/envs.md.
"""
from __future__ import annotations

from gymnasium.envs.registration import register, registry

from etb_gym.plant import MODELS

ENV_IDS = tuple(f"ETB-{m}-v0" for m in MODELS)


def register_envs() -> None:
    """Register the nine ids (idempotent)."""
    for m, env_id in zip(MODELS, ENV_IDS):
        if env_id not in registry:
            register(id=env_id, entry_point="etb_gym.envs.env:ETBEnv",
                     vector_entry_point="etb_gym.envs.vector:ETBVectorEnv", kwargs={"model": m})


register_envs()

__all__ = ["ENV_IDS", "register_envs"]
