"""Learner configuration (train/config.py): defaults and validation messages."""

import dataclasses

import pytest

from train.config import AgentConfig, LoopConfig, ReplayConfig, SACConfig, TrainConfig


def test_defaults_are_the_paper_budget():
    cfg = TrainConfig(agent=AgentConfig("egru"))
    assert cfg.agent.hidden == (128, 256, 64) and cfg.agent.gru_hidden == 32 and cfg.agent.stack == 5
    assert (cfg.sac.lr, cfg.sac.batch_size, cfg.sac.tau, cfg.sac.gamma) == (1e-3, 256, 0.05, 0.95)
    assert cfg.sac.resolved_target_entropy(3) == -3.0
    assert SACConfig(target_entropy=-1.5).resolved_target_entropy(3) == -1.5
    assert cfg.replay.capacity_transitions == 300_000 and cfg.replay.relabel_prob == pytest.approx(0.8)
    assert (cfg.loop.episode_len, cfg.loop.warmup_env_steps, cfg.loop.utd) == (50, 10_000, 1.0)
    assert cfg.loop.num_iterations == 580  # 29,000 steps of one environment
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.sac.lr = 1.0  # type: ignore[misc]


def test_recurrent_agents():
    assert [AgentConfig(k).recurrent for k in ("vpm", "stacked", "ugru", "egru")] == [False, False, True, True]


def test_updates_per_iteration_counts_the_whole_batch():
    loop = LoopConfig(num_envs=16, episode_len=50, utd=0.5)
    assert loop.env_steps_per_iteration == 800 and loop.updates_per_iteration == 400


@pytest.mark.parametrize(
    "make, message",
    [
        (lambda: SACConfig(gamma=1.5), r"sac\.gamma must be in \(0, 1\], got 1\.5"),
        (lambda: SACConfig(tau=0.0), r"sac\.tau must be in \(0, 1\]"),
        (lambda: SACConfig(lr=-1.0), r"sac\.lr must be"),
        (lambda: SACConfig(batch_size=0), r"sac\.batch_size must be a positive int"),
        (lambda: SACConfig(init_alpha=0.0), r"sac\.init_alpha"),
        (lambda: AgentConfig("lstm"), r"agent\.kind must be one of"),
        (lambda: AgentConfig("vpm", hidden=()), r"agent\.hidden"),
        (lambda: AgentConfig("ugru", gru_hidden=0), r"agent\.gru_hidden"),
        (lambda: ReplayConfig(her_k=-1), r"replay\.her_k"),
        (lambda: ReplayConfig(success_tau=0.0), r"replay\.success_tau"),
        (lambda: LoopConfig(num_envs=0), r"loop\.num_envs"),
        (lambda: LoopConfig(utd=-1.0), r"loop\.utd"),
        (lambda: LoopConfig(num_envs=1, episode_len=50, utd=0.011), r"loop\.utd .*whole number"),
        (
            lambda: TrainConfig(
                AgentConfig("vpm"), replay=ReplayConfig(capacity_transitions=100), loop=LoopConfig(num_envs=4)
            ),
            r"replay\.capacity_transitions must be at least .* = 200",
        ),
    ],
)
def test_validation_names_the_field(make, message):
    with pytest.raises(ValueError, match=message):
        make()
