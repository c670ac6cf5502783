"""Typed, frozen configuration of the SAC + HER learner (docs/task.md section 6).

Field defaults are the reference's learner (one environment, 29,000 environment steps, no
normalisation, symmetric critics, no demonstrations), so a record written before a field existed
reads back as what it trained with; the presets (train/presets.py) choose the measured settings.
Every field is checked in ``__post_init__`` so a bad value fails at construction with the field's
name, not deep inside a jit trace.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Literal, get_args

import jax.numpy as jnp

from mjx_push.config import EnvConfig
from mjx_push.expert import ExpertConfig
from mjx_push.errors import ConfigError

# The agent kinds, defined here once (the command line, the presets and reproduce take them from here;
# export/policy_file.py keeps a NumPy-side copy that a test holds equal).
AgentKind = Literal["vpm", "stacked", "ugru", "egru"]
AGENT_KINDS: tuple[str, ...] = get_args(AgentKind)
CriticObs = Literal["actor", "privileged"]
CRITIC_OBS: tuple[str, ...] = ("actor", "privileged")
# What the actor minimises: "sac" (SAC's objective, plus the cloning term when bc_weight > 0) or "bc"
# (the cloning term alone: DAgger with the scripted expert; the critics still learn, the actor never
# reads them).
ActorLoss = Literal["sac", "bc"]
ACTOR_LOSSES: tuple[str, ...] = get_args(ActorLoss)
# The protocol's settings (mjx_push.train.evaluate) that in-run evaluations can score.
EvalSetting = Literal["standard", "difficult"]
EVAL_SETTINGS: tuple[str, ...] = get_args(EvalSetting)


def _check(ok: bool, name: str, requirement: str, value) -> None:
    if not ok:
        raise ConfigError(f"{name} must be {requirement}, got {value!r}")


def _positive_int(name: str, value) -> None:
    _check(isinstance(value, int) and not isinstance(value, bool) and value > 0, name, "a positive int", value)


def _widths(name: str, value: tuple) -> None:
    _check(
        len(value) > 0 and all(isinstance(h, int) and not isinstance(h, bool) and h > 0 for h in value),
        name,
        "a non-empty tuple of positive ints",
        value,
    )


def _fraction(name: str, value) -> None:
    _check(
        isinstance(value, (int, float)) and not isinstance(value, bool) and 0 <= value <= 1,
        name,
        "a number in [0, 1]",
        value,
    )


@dataclasses.dataclass(frozen=True)
class AgentConfig:
    """Which feature extractor the actor and the critics use, and the MLP sizes."""

    kind: AgentKind
    hidden: tuple[int, ...] = (128, 256, 64)  # the actor's MLP (and the critics' unless critic_hidden)
    gru_hidden: int = 32
    stack: int = 5
    critic_hidden: tuple[int, ...] | None = None  # None: the same as ``hidden``
    critic_layer_norm: bool = False  # LayerNorm after every hidden layer of the critics
    # "actor": each critic has its own feature extractor over the actor's observation (the paper);
    # "privileged": an MLP critic over the simulator's ground truth (object pose, velocity, mass,
    # friction, size, the flange's true position and velocity) and the goal xy. The actor, and so
    # everything exported, keeps the paper's observation.
    critic_obs: CriticObs = "actor"
    # Running mean/std normalisation of the networks' inputs, clipped to +-norm_clip. The actor's
    # statistics live in its parameters (collection "norm"), so saved and exported policies carry them.
    obs_norm: bool = False
    norm_clip: float = 5.0

    def __post_init__(self):
        _check(self.kind in AGENT_KINDS, "agent.kind", f"one of {AGENT_KINDS}", self.kind)
        # Accept lists (e.g. from a CLI) but store tuples so the config stays hashable.
        object.__setattr__(self, "hidden", tuple(self.hidden))
        _widths("agent.hidden", self.hidden)
        if self.critic_hidden is not None:
            object.__setattr__(self, "critic_hidden", tuple(self.critic_hidden))
            _widths("agent.critic_hidden", self.critic_hidden)
        _positive_int("agent.gru_hidden", self.gru_hidden)
        _positive_int("agent.stack", self.stack)
        _check(isinstance(self.critic_layer_norm, bool), "agent.critic_layer_norm", "a bool", self.critic_layer_norm)
        _check(self.critic_obs in CRITIC_OBS, "agent.critic_obs", f"one of {CRITIC_OBS}", self.critic_obs)
        _check(isinstance(self.obs_norm, bool), "agent.obs_norm", "a bool", self.obs_norm)
        _check(
            math.isfinite(self.norm_clip) and self.norm_clip > 0,
            "agent.norm_clip",
            "a finite number > 0",
            self.norm_clip,
        )

    @property
    def critic_widths(self) -> tuple[int, ...]:
        return self.hidden if self.critic_hidden is None else self.critic_hidden

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
    # Clip TD targets to the return's range [-1/(1-gamma), 0] (rewards are -1 or 0), as OpenAI's HER.
    target_clip: bool = False
    # Behaviour cloning on expert demonstrations (Nair et al. 2018): the actor loss adds bc_weight times
    # the squared distance between the deterministic action and the expert's, on a batch of
    # bc_batch_size demonstration steps; with q_filter only where the critic rates the expert's action
    # above the actor's. Needs demonstrations in replay (DemoConfig).
    bc_weight: float = 0.0
    bc_batch_size: int = 128
    q_filter: bool = True
    actor_loss: ActorLoss = "sac"
    # The actor held to its own past self as the teacher leaves (demo.anneal_start/anneal_end, the
    # KL-to-the-supervised-policy idea of AlphaStar, here a squared action distance): at anneal_start a
    # frozen copy of the actor is kept, and the actor loss adds anchor_weight * (1 - teacher scale)
    # times the squared distance between the actor's and the copy's deterministic actions on the
    # batch's states, so the cloning term's weight passes to the anchor as the teacher goes. The copy
    # never reads the expert again: the last stretch is the agent's own. 0: no anchor.
    anchor_weight: float = 0.0

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
        _check(isinstance(self.target_clip, bool), "sac.target_clip", "a bool", self.target_clip)
        _check(
            math.isfinite(self.bc_weight) and self.bc_weight >= 0,
            "sac.bc_weight",
            "a finite number >= 0",
            self.bc_weight,
        )
        _positive_int("sac.bc_batch_size", self.bc_batch_size)
        _check(
            math.isfinite(self.anchor_weight) and self.anchor_weight >= 0,
            "sac.anchor_weight",
            "a finite number >= 0",
            self.anchor_weight,
        )
        _check(isinstance(self.q_filter, bool), "sac.q_filter", "a bool", self.q_filter)
        _check(self.actor_loss in ACTOR_LOSSES, "sac.actor_loss", f"one of {ACTOR_LOSSES}", self.actor_loss)
        if self.actor_loss == "bc":
            _check(
                self.bc_weight > 0,
                "sac.bc_weight",
                "> 0 with sac.actor_loss 'bc' (the actor's only loss)",
                self.bc_weight,
            )
            _check(
                not self.q_filter,
                "sac.q_filter",
                "False with sac.actor_loss 'bc' (the filter reads the critics)",
                self.q_filter,
            )

    def resolved_target_entropy(self, action_dim: int) -> float:
        return -float(action_dim) if self.target_entropy is None else float(self.target_entropy)


@dataclasses.dataclass(frozen=True)
class ReplayConfig:
    capacity_transitions: int = 300_000
    her_k: int = 4  # relabel probability her_k / (her_k + 1)
    # The reward is -1 while the object is at least the task's success radius (the environment's, read
    # from the learner's EnvAdapter) from the goal, else 0.
    # Success-radius curriculum for the learner's rewards: the radius falls linearly from
    # curriculum_tau (None: no curriculum) to the task's radius over the first curriculum_env_steps env
    # steps after the warm-up. Evaluation always scores at the task's radius.
    curriculum_tau: float | None = None
    curriculum_env_steps: int = 0

    def __post_init__(self):
        _positive_int("replay.capacity_transitions", self.capacity_transitions)
        _check(
            isinstance(self.her_k, int) and not isinstance(self.her_k, bool) and self.her_k >= 0,
            "replay.her_k",
            "an int >= 0",
            self.her_k,
        )
        if self.curriculum_tau is not None:
            _check(
                math.isfinite(self.curriculum_tau) and self.curriculum_tau > 0,
                "replay.curriculum_tau",
                "None or a number > 0 (metres)",
                self.curriculum_tau,
            )
            _positive_int("replay.curriculum_env_steps", self.curriculum_env_steps)
        _check(
            isinstance(self.curriculum_env_steps, int) and self.curriculum_env_steps >= 0,
            "replay.curriculum_env_steps",
            "an int >= 0",
            self.curriculum_env_steps,
        )

    def reward_tau(self, env_steps_after_warmup, success_tau: float):
        """The learner's success radius after this many env steps past the warm-up (traced or not), for
        a task of success radius ``success_tau``."""
        if self.curriculum_tau is None:
            return success_tau
        frac = jnp.clip(env_steps_after_warmup / self.curriculum_env_steps, 0.0, 1.0)
        return self.curriculum_tau + (success_tau - self.curriculum_tau) * frac

    @property
    def relabel_prob(self) -> float:
        return self.her_k / (self.her_k + 1)


@dataclasses.dataclass(frozen=True)
class DemoConfig:
    """Demonstrations from the environment's scripted expert (it reads the simulator's ground truth).

    Demonstration episodes go into replay like any other (HER relabels them too) and feed the
    behaviour-cloning term (SACConfig.bc_weight)."""

    warmup: bool = False  # the warm-up's episodes are the expert's instead of uniform random actions
    fraction: float = 0.0  # after the warm-up, this share of each batch's environments follows the expert
    noise: float = 0.0  # std of Gaussian noise on the expert's actions (more varied demonstrations)
    # Behaviour cloning on every stored step, labelled with what the expert would have done there
    # (DAgger-style: the agent learns the expert's action in the states it visits itself); False: on
    # the demonstration episodes only (Nair et al.).
    label_all: bool = False
    # The teacher annealed away: from anneal_start to anneal_end (environment steps) the cloning weight
    # and the expert's share of environments fall linearly to 0 and stay there, so the agent ends
    # training on its own. None: no annealing (the teacher stays to the end).
    anneal_start: int | None = None
    anneal_end: int | None = None
    # The anchor (SACConfig.anchor_weight) let go in turn: its weight, full at anneal_end, falls
    # linearly to 0 at anchor_release (env steps), so what follows is the agent's own critic alone.
    # None: the anchor holds to the end.
    anchor_release: int | None = None
    # False: the expert's episodes leave replay at anneal_end (marked invalid, never sampled again), so
    # the critics learn from the agent's own episodes alone once the teacher is gone. True: they stay
    # until the ring buffer overwrites them.
    keep_after_anneal: bool = True

    def __post_init__(self):
        _check(isinstance(self.warmup, bool), "demo.warmup", "a bool", self.warmup)
        if (self.anneal_start is None) != (self.anneal_end is None):
            raise ConfigError(
                "demo.anneal_start and demo.anneal_end must be given together (env steps), got "
                f"anneal_start={self.anneal_start!r}, anneal_end={self.anneal_end!r}"
            )
        if self.anneal_start is not None:
            for name in ("anneal_start", "anneal_end"):
                v = getattr(self, name)
                _check(
                    isinstance(v, int) and not isinstance(v, bool) and v >= 0,
                    f"demo.{name}",
                    "an int >= 0 (env steps)",
                    v,
                )
            _check(
                self.anneal_end > self.anneal_start,
                "demo.anneal_end",
                f"greater than demo.anneal_start ({self.anneal_start})",
                self.anneal_end,
            )
        _check(isinstance(self.keep_after_anneal, bool), "demo.keep_after_anneal", "a bool", self.keep_after_anneal)
        if self.anneal_start is None:
            _check(
                self.anchor_release is None,
                "demo.anchor_release",
                "None unless the teacher is annealed",
                self.anchor_release,
            )
            _check(
                self.keep_after_anneal,
                "demo.keep_after_anneal",
                "True unless the teacher is annealed",
                self.keep_after_anneal,
            )
        elif self.anchor_release is not None:
            _check(
                isinstance(self.anchor_release, int)
                and not isinstance(self.anchor_release, bool)
                and self.anchor_release > self.anneal_end,
                "demo.anchor_release",
                f"None or an int greater than demo.anneal_end ({self.anneal_end}) (env steps)",
                self.anchor_release,
            )
        _check(isinstance(self.label_all, bool), "demo.label_all", "a bool", self.label_all)
        _fraction("demo.fraction", self.fraction)
        _check(math.isfinite(self.noise) and self.noise >= 0, "demo.noise", "a finite number >= 0", self.noise)

    @property
    def enabled(self) -> bool:
        return self.warmup or self.fraction > 0

    def teacher_scale(self, env_steps):
        """The factor (1 -> 0) on the cloning weight and the expert's share after ``env_steps``
        environment steps (a Python number or a traced array): 1 without annealing."""
        if self.anneal_start is None:
            return 1.0 if isinstance(env_steps, (int, float)) else jnp.ones((), jnp.float32)
        span = float(self.anneal_end - self.anneal_start)
        if isinstance(env_steps, (int, float)):
            return min(max((self.anneal_end - env_steps) / span, 0.0), 1.0)
        return jnp.clip((self.anneal_end - env_steps) / span, 0.0, 1.0).astype(jnp.float32)

    def anchor_scale(self, env_steps):
        """The factor (0 -> 1 -> 0) on the anchor's weight after ``env_steps`` environment steps: it takes
        over the cloning weight as the teacher goes (1 - teacher_scale), then falls from anneal_end to
        0 at ``anchor_release`` (stays 1 without a release). 0 without annealing."""
        if self.anneal_start is None:
            return 0.0 if isinstance(env_steps, (int, float)) else jnp.zeros((), jnp.float32)
        taken = 1.0 - self.teacher_scale(env_steps)
        if self.anchor_release is None:
            return taken
        span = float(self.anchor_release - self.anneal_end)
        if isinstance(env_steps, (int, float)):
            return min(taken, min(max((self.anchor_release - env_steps) / span, 0.0), 1.0))
        held = jnp.clip((self.anchor_release - env_steps) / span, 0.0, 1.0).astype(jnp.float32)
        return jnp.minimum(taken, held)

    def teacher_gone(self, env_steps):
        """Whether the teacher has left for good after ``env_steps`` env steps (a Python number or a
        traced array; never without annealing)."""
        return self.anneal_end is not None and env_steps >= self.anneal_end


@dataclasses.dataclass(frozen=True)
class LoopConfig:
    num_envs: int = 1
    total_env_steps: int = 29_000
    warmup_env_steps: int = 10_000  # uniform random actions, no learning, before this many env steps
    utd: float = 1.0  # gradient updates per env step of ONE env: a batch of N env steps gives N * utd updates
    eval_every_env_steps: int = 5_000
    eval_episodes: int = 100
    seed: int = 0
    # In-run evaluations (and the best-actor selection) score the protocol's episodes of this setting,
    # drawn from eval_seed with uniform sampling whatever the agent trains on, so every agent and every
    # training seed is scored on the same objects. The seed differs from the protocol's test seed
    # (mjx_push.train.episodes.EvalSpec), so the actor a report scores was not selected on its episodes.
    eval_setting: EvalSetting = "standard"
    eval_seed: int = 2_000_003
    # Data-parallel devices (over every process of a multi-machine run, train/data_parallel.py): each
    # steps num_envs / data_parallel environments, holds that share of the replay buffer and samples
    # that share of every batch; gradients are averaged over all of them. 1: one device learns.
    data_parallel: int = 1

    def __post_init__(self):
        _positive_int("loop.num_envs", self.num_envs)
        _positive_int("loop.data_parallel", self.data_parallel)
        _check(
            self.num_envs % self.data_parallel == 0,
            "loop.num_envs",
            f"a multiple of loop.data_parallel ({self.data_parallel})",
            self.num_envs,
        )
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
        _check(self.eval_setting in EVAL_SETTINGS, "loop.eval_setting", f"one of {EVAL_SETTINGS}", self.eval_setting)
        _check(
            isinstance(self.eval_seed, int) and not isinstance(self.eval_seed, bool),
            "loop.eval_seed",
            "an int",
            self.eval_seed,
        )

    # The counts of a batch of episodes of the task's length (the environment's, `EnvAdapter.episode_len`).
    def env_steps_per_iteration(self, episode_len: int) -> int:
        return self.num_envs * episode_len

    def updates_per_iteration(self, episode_len: int) -> int:
        return int(round(self.num_envs * episode_len * self.utd))

    def num_iterations(self, episode_len: int) -> int:
        return -(-self.total_env_steps // self.env_steps_per_iteration(episode_len))


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    agent: AgentConfig
    sac: SACConfig = SACConfig()
    replay: ReplayConfig = ReplayConfig()
    loop: LoopConfig = LoopConfig()
    demo: DemoConfig = DemoConfig()

    def __post_init__(self):
        for name, cls in (
            ("agent", AgentConfig),
            ("sac", SACConfig),
            ("replay", ReplayConfig),
            ("loop", LoopConfig),
            ("demo", DemoConfig),
        ):
            _check(isinstance(getattr(self, name), cls), name, f"a {cls.__name__}", getattr(self, name))
        _check(
            self.sac.bc_weight == 0 or self.demo.enabled,
            "sac.bc_weight",
            "0 unless demonstrations are collected (demo.warmup or demo.fraction > 0)",
            self.sac.bc_weight,
        )
        _check(
            self.sac.anchor_weight == 0 or self.demo.anneal_start is not None,
            "sac.anchor_weight",
            "0 unless the teacher is annealed (demo.anneal_start and demo.anneal_end set; the anchor is the "
            "actor at anneal_start)",
            self.sac.anchor_weight,
        )
        if self.demo.anneal_start is not None:
            _check(
                self.demo.enabled,
                "demo.anneal_start",
                "None unless demonstrations are collected",
                self.demo.anneal_start,
            )
            _check(
                self.sac.actor_loss == "sac",
                "demo.anneal_start",
                "None with sac.actor_loss 'bc' (annealing the only loss away leaves the actor nothing to learn)",
                self.demo.anneal_start,
            )
            _check(
                self.demo.anneal_start >= self.loop.warmup_env_steps,
                "demo.anneal_start",
                f"at or after the warm-up (loop.warmup_env_steps = {self.loop.warmup_env_steps})",
                self.demo.anneal_start,
            )
            _check(
                self.demo.anneal_end <= self.loop.total_env_steps,
                "demo.anneal_end",
                f"at most loop.total_env_steps ({self.loop.total_env_steps})",
                self.demo.anneal_end,
            )

    def check_task(self, episode_len: int, success_tau: float) -> None:
        """The checks that need the task's facts, the environment's episode length and success radius
        (``make_train`` reads them from its adapter; ``RunConfig`` from its ``env``). Raises ConfigError
        naming the learner's field."""
        loop, replay = self.loop, self.replay
        # The number of updates per episode batch is a static scan length, so it must be whole.
        n = loop.num_envs * episode_len * loop.utd
        _check(
            abs(n - round(n)) < 1e-6,
            "loop.utd",
            f"such that num_envs * episode_len ({episode_len}, the task's) * utd is a whole number (it is {n})",
            loop.utd,
        )
        # The ring buffer stores whole episodes; one collection batch must fit without overwriting itself.
        _check(
            replay.capacity_transitions // episode_len >= loop.num_envs,
            "replay.capacity_transitions",
            f"at least loop.num_envs * the task's episode length = {loop.num_envs * episode_len}",
            replay.capacity_transitions,
        )
        if replay.curriculum_tau is not None:
            _check(
                replay.curriculum_tau >= success_tau,
                "replay.curriculum_tau",
                f"None or a number >= the task's success radius ({success_tau})",
                replay.curriculum_tau,
            )


Preset = Literal["smoke", "cpu", "cpu-long", "teacher-free", "reference", "paper"]  # defined here once
PRESETS: tuple[str, ...] = get_args(Preset)


@dataclasses.dataclass(frozen=True)
class RunConfig:
    """A whole run: the agent, the preset it came from, the learner, the task, the encoder and the
    scripted expert; a run's config.json holds every value (`mjx_push.train.presets.config_dict`)."""

    agent: str
    preset: str
    train: TrainConfig
    env: EnvConfig
    # Encoder weights to train with (msgpack); None: the shipped pretrained encoder. Saved policies carry
    # the weights themselves, so this is provenance once training is done.
    encoder: str | None = None
    expert: ExpertConfig = ExpertConfig()  # the scripted expert's settings (demonstrations, baseline)

    def __post_init__(self):
        if self.agent not in AGENT_KINDS:
            raise ConfigError(f"agent must be one of {AGENT_KINDS}, got {self.agent!r}")
        if self.preset not in PRESETS:
            raise ConfigError(f"preset must be one of {PRESETS}, got {self.preset!r}")
        if self.train.agent.kind != self.agent:
            raise ConfigError(f"train.agent.kind ({self.train.agent.kind!r}) must equal agent ({self.agent!r})")
        self.train.check_task(self.env.episode_length, self.env.success_tau)  # the learner's checks on the task
        if self.env.objects.shape == "any" and self.train.loop.num_envs < 2:
            raise ConfigError("train.loop.num_envs must be >= 2 with shape filter 'any' (one group per shape)")
