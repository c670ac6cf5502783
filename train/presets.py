"""Run configurations: the learner's `TrainConfig`, the task's `EnvConfig` and the encoder, with the
three presets of `mjx-push train --preset`.

* ``smoke``: the whole pipeline (rollouts, warm-up, updates, evaluation, checkpoints, best policy) on
  2 CPU cores in a few minutes; it proves the plumbing, not the policy.
* ``paper``: the reference budget of SPEC section 6: 29,000 environment steps, 10,000 random-action
  steps, one gradient step per environment step (19,000 updates), batch 256, replay 3e5 transitions,
  evaluation every 5,000 steps on 100 deterministic episodes. The reference ran one environment; we
  run 10 in parallel with the same totals (the update count per environment step is unchanged), which
  cuts wall time on CPU but means the policy is refreshed every 500 steps instead of every step.
* ``gpu``: sized for one H100: 2,048 environments, 3 million environment steps, a lower update-to-data
  ratio with a larger batch (0.05 updates per environment step at batch 1,024, i.e. ~5 % more samples
  drawn per step than the paper's 1 x 256).

eGRU differs from uGRU only in the environment: the improved force sampling (SPEC section 4).
"""

from __future__ import annotations

import dataclasses
from typing import Literal

from mjx_push import objects
from mjx_push.env import EnvConfig
from train.config import AGENT_KINDS, AgentConfig, LoopConfig, ReplayConfig, SACConfig, TrainConfig

Preset = Literal["smoke", "paper", "gpu"]
PRESETS: tuple[str, ...] = ("smoke", "paper", "gpu")


@dataclasses.dataclass(frozen=True)
class RunConfig:
    agent: str
    preset: str
    train: TrainConfig
    env: EnvConfig
    # Encoder weights to train with (msgpack); None: the shipped pretrained encoder. Saved policies carry
    # the weights themselves, so this is provenance once training is done.
    encoder: str | None = None

    def __post_init__(self):
        if self.agent not in AGENT_KINDS:
            raise ValueError(f"agent must be one of {AGENT_KINDS}, got {self.agent!r}")
        if self.preset not in PRESETS:
            raise ValueError(f"preset must be one of {PRESETS}, got {self.preset!r}")
        if self.train.agent.kind != self.agent:
            raise ValueError(f"train.agent.kind ({self.train.agent.kind!r}) must equal agent ({self.agent!r})")
        if self.train.loop.episode_len != self.env.episode_length:
            raise ValueError(
                f"train.loop.episode_len ({self.train.loop.episode_len}) must equal env.episode_length "
                f"({self.env.episode_length})"
            )
        if abs(self.train.replay.success_tau - self.env.success_tau) > 1e-12:
            raise ValueError("train.replay.success_tau must equal env.success_tau")
        if self.env.objects.shape == "any" and self.train.loop.num_envs < 2:
            raise ValueError("train.loop.num_envs must be >= 2 with shape filter 'any' (one group per shape)")


def env_for(agent: str, objects_cfg: objects.ObjectConfig | None = None, **env_fields) -> EnvConfig:
    """The task an agent trains on: eGRU draws masses with the improved sampling."""
    objects_cfg = objects_cfg or objects.ObjectConfig()
    mode = "improved" if agent == "egru" else "uniform"
    return EnvConfig(objects=dataclasses.replace(objects_cfg, mode=mode), **env_fields)


_LOOPS = {
    # One batch of random-action episodes, 100 updates, one evaluation: two rollouts in all, since on
    # 2 CPU cores compilation plus each 50-step rollout (~40 s) is the whole cost.
    "smoke": dict(num_envs=8, total_env_steps=400, warmup_env_steps=400, utd=0.25, eval_every_env_steps=400,
                  eval_episodes=8),
    "paper": dict(num_envs=10, total_env_steps=29_000, warmup_env_steps=10_000, utd=1.0,
                  eval_every_env_steps=5_000, eval_episodes=100),
    "gpu": dict(num_envs=2048, total_env_steps=3_072_000, warmup_env_steps=102_400, utd=0.05,
                eval_every_env_steps=204_800, eval_episodes=2048),
}
_SAC = {"smoke": dict(batch_size=64), "paper": dict(batch_size=256), "gpu": dict(batch_size=1024)}
_REPLAY = {"smoke": 50_000, "paper": 300_000, "gpu": 2_000_000}


def make(agent: str, preset: str = "smoke", seed: int = 0) -> RunConfig:
    if preset not in PRESETS:
        raise ValueError(f"preset must be one of {PRESETS}, got {preset!r}")
    if agent not in AGENT_KINDS:
        raise ValueError(f"agent must be one of {AGENT_KINDS}, got {agent!r}")
    env = env_for(agent)
    train = TrainConfig(
        agent=AgentConfig(agent),
        sac=SACConfig(**_SAC[preset]),
        replay=ReplayConfig(capacity_transitions=_REPLAY[preset], success_tau=env.success_tau),
        loop=LoopConfig(episode_len=env.episode_length, seed=seed, **_LOOPS[preset]),
    )
    return RunConfig(agent=agent, preset=preset, train=train, env=env)


def override(cfg: RunConfig, **fields) -> RunConfig:
    """Replace learner fields by dotted name, e.g. override(cfg, **{"loop.num_envs": 16, "sac.lr": 3e-4});
    None values are ignored. The preset name stays that of the base; the run's config.json holds every value."""
    train = cfg.train
    for dotted, value in fields.items():
        if value is None:
            continue
        section, name = dotted.split(".")
        sub = getattr(train, section)
        if not hasattr(sub, name):
            raise ValueError(f"unknown setting {dotted!r}")
        train = dataclasses.replace(train, **{section: dataclasses.replace(sub, **{name: value})})
    return dataclasses.replace(cfg, train=train)
