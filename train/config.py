"""Typed, frozen configuration of the SAC + HER learner (SPEC section 6).

Defaults are the "paper budget" of the reference (one environment, 29,000 environment steps). Every
field is checked in ``__post_init__`` so a bad value fails at construction with the field's name, not
deep inside a jit trace.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Literal

AgentKind = Literal["vpm", "stacked", "ugru", "egru"]
AGENT_KINDS: tuple[str, ...] = ("vpm", "stacked", "ugru", "egru")


def _check(ok: bool, name: str, requirement: str, value) -> None:
    if not ok:
        raise ValueError(f"{name} must be {requirement}, got {value!r}")


def _positive_int(name: str, value) -> None:
    _check(isinstance(value, int) and not isinstance(value, bool) and value > 0, name, "a positive int", value)


@dataclasses.dataclass(frozen=True)
class AgentConfig:
    """Which feature extractor the actor and the critics use, and the MLP sizes."""

    kind: AgentKind
    hidden: tuple[int, ...] = (128, 256, 64)
    gru_hidden: int = 32
    stack: int = 5

    def __post_init__(self):
        _check(self.kind in AGENT_KINDS, "agent.kind", f"one of {AGENT_KINDS}", self.kind)
        # Accept lists (e.g. from a CLI) but store a tuple so the config stays hashable.
        object.__setattr__(self, "hidden", tuple(self.hidden))
        _check(
            len(self.hidden) > 0
            and all(isinstance(h, int) and not isinstance(h, bool) and h > 0 for h in self.hidden),
            "agent.hidden",
            "a non-empty tuple of positive ints",
            self.hidden,
        )
        _positive_int("agent.gru_hidden", self.gru_hidden)
        _positive_int("agent.stack", self.stack)

    @property
    def recurrent(self) -> bool:
        # uGRU and eGRU share the network; they differ only in the simulator's mass sampling.
        return self.kind in ("ugru", "egru")


@dataclasses.dataclass(frozen=True)
class SACConfig:
    lr: float = 1e-3
    lr_decay: bool = False  # linear decay to 0 over the run's gradient updates
    batch_size: int = 256
    tau: float = 0.05
    gamma: float = 0.95
    target_entropy: float | None = None  # None -> -action_dim
    init_alpha: float = 1.0

    def __post_init__(self):
        _check(math.isfinite(self.lr) and self.lr > 0, "sac.lr", "a finite number > 0", self.lr)
        _check(isinstance(self.lr_decay, bool), "sac.lr_decay", "a bool", self.lr_decay)
        _positive_int("sac.batch_size", self.batch_size)
        _check(0 < self.tau <= 1, "sac.tau", "in (0, 1]", self.tau)
        _check(0 < self.gamma <= 1, "sac.gamma", "in (0, 1]", self.gamma)
        _check(
            self.target_entropy is None or math.isfinite(self.target_entropy),
            "sac.target_entropy",
            "None or a finite number",
            self.target_entropy,
        )
        _check(
            math.isfinite(self.init_alpha) and self.init_alpha > 0,
            "sac.init_alpha",
            "a finite number > 0",
            self.init_alpha,
        )

    def resolved_target_entropy(self, action_dim: int) -> float:
        return -float(action_dim) if self.target_entropy is None else float(self.target_entropy)


@dataclasses.dataclass(frozen=True)
class ReplayConfig:
    capacity_transitions: int = 300_000
    her_k: int = 4  # relabel probability her_k / (her_k + 1)
    success_tau: float = 0.01  # metres; reward is -1 while the object is this far or farther from the goal

    def __post_init__(self):
        _positive_int("replay.capacity_transitions", self.capacity_transitions)
        _check(
            isinstance(self.her_k, int) and not isinstance(self.her_k, bool) and self.her_k >= 0,
            "replay.her_k",
            "an int >= 0",
            self.her_k,
        )
        _check(math.isfinite(self.success_tau) and self.success_tau > 0, "replay.success_tau", "> 0", self.success_tau)

    @property
    def relabel_prob(self) -> float:
        return self.her_k / (self.her_k + 1)


@dataclasses.dataclass(frozen=True)
class LoopConfig:
    num_envs: int = 1
    episode_len: int = 50
    total_env_steps: int = 29_000
    warmup_env_steps: int = 10_000  # uniform random actions, no learning, before this many env steps
    utd: float = 1.0  # gradient updates per env step of ONE env: a batch of N env steps gives N * utd updates
    eval_every_env_steps: int = 5_000
    eval_episodes: int = 100
    seed: int = 0

    def __post_init__(self):
        _positive_int("loop.num_envs", self.num_envs)
        _positive_int("loop.episode_len", self.episode_len)
        _positive_int("loop.total_env_steps", self.total_env_steps)
        _check(
            isinstance(self.warmup_env_steps, int) and self.warmup_env_steps >= 0,
            "loop.warmup_env_steps",
            "an int >= 0",
            self.warmup_env_steps,
        )
        _check(math.isfinite(self.utd) and self.utd >= 0, "loop.utd", "a finite number >= 0", self.utd)
        _positive_int("loop.eval_every_env_steps", self.eval_every_env_steps)
        _positive_int("loop.eval_episodes", self.eval_episodes)
        _check(isinstance(self.seed, int) and not isinstance(self.seed, bool), "loop.seed", "an int", self.seed)
        # The number of updates per episode batch is a static scan length, so it must be whole.
        n = self.num_envs * self.episode_len * self.utd
        _check(
            abs(n - round(n)) < 1e-6,
            "loop.utd",
            f"such that num_envs * episode_len * utd is a whole number (it is {n})",
            self.utd,
        )

    @property
    def env_steps_per_iteration(self) -> int:
        return self.num_envs * self.episode_len

    @property
    def updates_per_iteration(self) -> int:
        return int(round(self.num_envs * self.episode_len * self.utd))

    @property
    def num_iterations(self) -> int:
        return -(-self.total_env_steps // self.env_steps_per_iteration)


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    agent: AgentConfig
    sac: SACConfig = SACConfig()
    replay: ReplayConfig = ReplayConfig()
    loop: LoopConfig = LoopConfig()

    def __post_init__(self):
        for name, cls in (("agent", AgentConfig), ("sac", SACConfig), ("replay", ReplayConfig), ("loop", LoopConfig)):
            _check(isinstance(getattr(self, name), cls), name, f"a {cls.__name__}", getattr(self, name))
        # The ring buffer stores whole episodes; one collection batch must fit without overwriting itself.
        capacity_episodes = self.replay.capacity_transitions // self.loop.episode_len
        _check(
            capacity_episodes >= self.loop.num_envs,
            "replay.capacity_transitions",
            f"at least loop.num_envs * loop.episode_len = {self.loop.num_envs * self.loop.episode_len}",
            self.replay.capacity_transitions,
        )
