"""Learner configuration (train/config.py): defaults and validation messages."""

import mjx_push.train  # noqa: F401  (applies the XLA CPU flag before JAX starts)

import dataclasses

import jax.numpy as jnp
import pytest

from mjx_push.config import EnvConfig
from mjx_push.train.config import AgentConfig, DemoConfig, LoopConfig, ReplayConfig, SACConfig, TrainConfig


def test_defaults_are_the_paper_budget():
    cfg = TrainConfig(agent=AgentConfig("egru"))
    assert cfg.agent.hidden == (128, 256, 64) and cfg.agent.gru_hidden == 32 and cfg.agent.stack == 5
    assert (cfg.sac.lr, cfg.sac.batch_size, cfg.sac.tau, cfg.sac.gamma) == (1e-3, 256, 0.05, 0.95)
    assert cfg.sac.resolved_target_entropy(3) == -3.0
    assert SACConfig(target_entropy=-1.5).resolved_target_entropy(3) == -1.5
    assert cfg.replay.capacity_transitions == 300_000 and cfg.replay.relabel_prob == pytest.approx(0.8)
    assert (EnvConfig().episode_length, cfg.loop.warmup_env_steps, cfg.loop.utd) == (50, 10_000, 1.0)
    assert cfg.loop.num_iterations(EnvConfig().episode_length) == 580  # 29,000 steps of one environment
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.sac.lr = 1.0  # type: ignore[misc]


def test_recurrent_agents():
    assert [AgentConfig(k).recurrent for k in ("vpm", "stacked", "ugru", "egru")] == [False, False, True, True]


def test_updates_per_iteration_counts_the_whole_batch():
    loop = LoopConfig(num_envs=16, utd=0.5)
    assert loop.env_steps_per_iteration(50) == 800 and loop.updates_per_iteration(50) == 400


def _annealed(sac=None, warmup=True, fraction=0.25, **demo):
    return TrainConfig(
        AgentConfig("vpm"),
        sac=sac or SACConfig(bc_weight=1.0),
        loop=LoopConfig(total_env_steps=10_000, warmup_env_steps=1_000),
        demo=DemoConfig(warmup=warmup, fraction=fraction, **demo),
    )


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
        (lambda: EnvConfig(success_tau=0.0), r"env\.success_tau must be > 0"),
        (lambda: LoopConfig(num_envs=0), r"loop\.num_envs"),
        (lambda: LoopConfig(utd=-1.0), r"loop\.utd"),
        (
            lambda: TrainConfig(AgentConfig("vpm"), loop=LoopConfig(num_envs=1, utd=0.011)).check_task(50, 0.01),
            r"loop\.utd .*whole number",
        ),
        (lambda: AgentConfig("vpm", critic_hidden=(256, 0)), r"agent\.critic_hidden must be a non-empty tuple"),
        (lambda: AgentConfig("vpm", critic_obs="state"), r"agent\.critic_obs must be one of \('actor', 'privileged'\)"),
        (lambda: AgentConfig("vpm", critic_layer_norm="yes"), r"agent\.critic_layer_norm must be a bool"),
        (lambda: AgentConfig("vpm", obs_norm=1), r"agent\.obs_norm must be a bool"),
        (lambda: AgentConfig("vpm", norm_clip=0.0), r"agent\.norm_clip must be a finite number > 0"),
        (lambda: SACConfig(target_clip=None), r"sac\.target_clip must be a bool"),
        (lambda: SACConfig(bc_weight=-1.0), r"sac\.bc_weight must be a finite number >= 0"),
        (lambda: SACConfig(bc_batch_size=0), r"sac\.bc_batch_size must be a positive int"),
        (lambda: SACConfig(q_filter="no"), r"sac\.q_filter must be a bool"),
        (
            lambda: TrainConfig(
                AgentConfig("vpm"), replay=ReplayConfig(curriculum_tau=0.005, curriculum_env_steps=10)
            ).check_task(50, 0.01),
            r"replay\.curriculum_tau must be None or a number >= the task's success radius \(0\.01\)",
        ),
        (lambda: ReplayConfig(curriculum_tau=0.0, curriculum_env_steps=10), r"replay\.curriculum_tau must be None or"),
        (lambda: ReplayConfig(curriculum_tau=0.05), r"replay\.curriculum_env_steps must be a positive int"),
        (lambda: ReplayConfig(curriculum_env_steps=-5), r"replay\.curriculum_env_steps must be an int >= 0"),
        (lambda: DemoConfig(fraction=1.5), r"demo\.fraction must be a number in \[0, 1\]"),
        (lambda: DemoConfig(noise=-0.1), r"demo\.noise must be a finite number >= 0"),
        (lambda: DemoConfig(warmup="yes"), r"demo\.warmup must be a bool"),
        (
            lambda: TrainConfig(AgentConfig("vpm"), sac=SACConfig(bc_weight=1.0)),
            r"sac\.bc_weight must be 0 unless demonstrations are collected",
        ),
        (lambda: SACConfig(actor_loss="dagger"), r"sac\.actor_loss must be one of \('sac', 'bc'\)"),
        (lambda: SACConfig(actor_loss="bc"), r"sac\.bc_weight must be > 0 with sac\.actor_loss 'bc'"),
        (lambda: SACConfig(actor_loss="bc", bc_weight=1.0), r"sac\.q_filter must be False with sac\.actor_loss 'bc'"),
        (lambda: DemoConfig(anneal_start=100), r"demo\.anneal_start and demo\.anneal_end must be given together"),
        (
            lambda: DemoConfig(anneal_start=500, anneal_end=500),
            r"demo\.anneal_end must be greater than demo\.anneal_start \(500\)",
        ),
        (lambda: DemoConfig(anneal_start=-1, anneal_end=5), r"demo\.anneal_start must be an int >= 0"),
        (lambda: DemoConfig(anneal_start=0, anneal_end=2.5), r"demo\.anneal_end must be an int >= 0"),
        (
            lambda: _annealed(anneal_start=100, anneal_end=5_000),
            r"demo\.anneal_start must be at or after the warm-up \(loop\.warmup_env_steps = 1000\)",
        ),
        (
            lambda: _annealed(anneal_start=2_000, anneal_end=20_000),
            r"demo\.anneal_end must be at most loop\.total_env_steps \(10000\)",
        ),
        (
            lambda: _annealed(anneal_start=2_000, anneal_end=5_000, warmup=False, fraction=0.0, sac=SACConfig()),
            r"demo\.anneal_start must be None unless demonstrations are collected",
        ),
        (
            lambda: _annealed(
                anneal_start=2_000, anneal_end=5_000, sac=SACConfig(actor_loss="bc", bc_weight=1.0, q_filter=False)
            ),
            r"demo\.anneal_start must be None with sac\.actor_loss 'bc'",
        ),
        (lambda: SACConfig(anchor_weight=-2.0), r"sac\.anchor_weight must be a finite number >= 0"),
        (
            lambda: _annealed(sac=SACConfig(bc_weight=1.0, anchor_weight=2.0)),
            r"sac\.anchor_weight must be 0 unless the teacher is annealed",
        ),
        (lambda: LoopConfig(eval_setting="custom"), r"loop\.eval_setting must be one of \('standard', 'difficult'\)"),
        (lambda: LoopConfig(eval_seed=1.5), r"loop\.eval_seed must be an int"),
        (
            lambda: TrainConfig(
                AgentConfig("vpm"), replay=ReplayConfig(capacity_transitions=100), loop=LoopConfig(num_envs=4)
            ).check_task(50, 0.01),  # episodes of 50 steps, the task's
            r"replay\.capacity_transitions must be at least .* = 200",
        ),
    ],
)
def test_validation_names_the_field(make, message):
    with pytest.raises(ValueError, match=message):
        make()


def test_curriculum_radius_falls_linearly_to_the_task_radius():
    r = ReplayConfig(curriculum_tau=0.05, curriculum_env_steps=1000)
    assert [float(r.reward_tau(s, 0.01)) for s in (0, 500, 1000, 5000)] == pytest.approx([0.05, 0.03, 0.01, 0.01])
    assert ReplayConfig().reward_tau(123, 0.02) == 0.02  # no curriculum


def test_teacher_annealing_falls_linearly_to_zero_at_its_end():
    d = DemoConfig(warmup=True, fraction=0.25, anneal_start=2_000, anneal_end=6_000)
    steps = (0, 2_000, 3_000, 5_000, 6_000, 9_000)
    assert [d.teacher_scale(s) for s in steps] == pytest.approx([1.0, 1.0, 0.75, 0.25, 0.0, 0.0])
    # The traced form (inside the jitted learner) agrees with the host's.
    assert [float(d.teacher_scale(jnp.asarray(s))) for s in steps] == pytest.approx([1.0, 1.0, 0.75, 0.25, 0.0, 0.0])
    assert DemoConfig(warmup=True).teacher_scale(10**6) == 1.0  # no annealing: the teacher stays


def test_paper_values_stay_the_field_defaults():
    """Old records read back as what they trained with: new features are off unless a preset sets them."""
    a, s, d = AgentConfig("vpm"), SACConfig(), DemoConfig()
    assert (a.obs_norm, a.critic_obs, a.critic_layer_norm, a.critic_widths) == (False, "actor", False, (128, 256, 64))
    assert (s.init_alpha, s.target_clip, s.bc_weight, s.actor_loss) == (1.0, False, 0.0, "sac")
    assert (d.anneal_start, d.anneal_end) == (None, None)
    assert not d.enabled and ReplayConfig().curriculum_tau is None


def test_the_task_facts_are_set_once_on_the_environment():
    from mjx_push.train import presets

    base = presets.make("vpm", "cpu")
    cfg = presets.with_overrides(base, {"env.episode_length": 30, "env.success_tau": 0.05})
    assert (cfg.env.episode_length, cfg.env.success_tau) == (30, 0.05)  # the learner has no copies to follow
    assert not hasattr(cfg.train.loop, "episode_len") and not hasattr(cfg.train.replay, "success_tau")
    assert presets.override(base, **{"loop.num_envs": 16, "sac.lr": None}).train.loop.num_envs == 16
    for copy, source in presets.REMOVED_TASK_COPIES.items():
        with pytest.raises(ValueError, match=rf"--set {copy}: .*environment; set {source} instead"):
            presets.with_overrides(base, {copy: 7})
    same = presets.with_overrides(base, {"train.replay.success_tau": 0.02, "env.success_tau": 0.02})
    assert same.env.success_tau == 0.02  # naming both, equal, is fine (the removed copy is ignored)
    assert presets.with_overrides(base, {"train.loop.episode_len": 50}) == base
    # The learner's checks that need the task's facts read the environment's.
    need = base.train.loop.num_envs * 300
    with pytest.raises(ValueError, match=rf"replay\.capacity_transitions must be at least .* = {need}"):
        presets.with_overrides(base, {"env.episode_length": 300, "train.replay.capacity_transitions": need - 1})


def _old_record(cfg, episode_len=None, success_tau=None) -> dict:
    """``cfg``'s dict as written before the learner's copies of the task's facts were removed."""
    from mjx_push.train import presets

    d = presets.config_dict(cfg)
    d["train"]["loop"]["episode_len"] = cfg.env.episode_length if episode_len is None else episode_len
    d["train"]["replay"]["success_tau"] = cfg.env.success_tau if success_tau is None else success_tau
    return d


def test_a_record_written_with_the_learners_copies_still_loads():
    """config.json, checkpoint, policy and exported-policy records written before the copies' removal
    hold train.loop.episode_len and train.replay.success_tau: equal to the environment's, they are
    dropped; different, the record is refused naming the field."""
    import json

    from mjx_push.train import presets

    cfg = presets.with_overrides(presets.make("ugru", "cpu", seed=3), {"env.success_tau": 0.05})
    old = _old_record(cfg)
    snapshot = json.dumps(old)
    assert presets.config_from_dict(old) == cfg
    assert json.dumps(old) == snapshot  # the record itself is left as it was
    partial = _old_record(cfg)
    del partial["train"]["replay"]["success_tau"]  # one copy only, and env's field left to its default
    del partial["env"]["episode_length"]
    assert presets.config_from_dict(partial) == cfg
    with pytest.raises(
        ValueError, match=r"config\.train\.loop\.episode_len \(30\) differs from config\.env\.episode_length \(50\)"
    ):
        presets.config_from_dict(_old_record(cfg, episode_len=30))
    with pytest.raises(
        ValueError,
        match=r"config\.train\.replay\.success_tau \(0\.01\) differs from config\.env\.success_tau \(0\.05\)",
    ):
        presets.config_from_dict(_old_record(cfg, success_tau=0.01))


def test_the_teacher_free_preset_is_cpu_long_then_the_teacher_annealed_away():
    """The comparison's recipe in one run: cpu-long's settings for its 64,000 env steps, then the
    cloning weight, the expert's share and the anchor on their schedule, by configuration alone."""
    from mjx_push.train import configio, presets
    from mjx_push.train.loop import spread_envs

    for agent in ("vpm", "egru"):
        recipe, long = presets.make(agent, "teacher-free"), presets.make(agent, "cpu-long")
        diff = configio.differences(presets.config_dict(long), presets.config_dict(recipe))
        assert sorted(d.split(":")[0] for d in diff) == [
            "preset",
            "train.demo.anneal_end",
            "train.demo.anneal_start",
            "train.loop.eval_every_env_steps",
            "train.loop.total_env_steps",
            "train.sac.anchor_weight",
        ]
    demo, sac, loop = recipe.train.demo, recipe.train.sac, recipe.train.loop
    steps = (32_000, 64_000, 72_000, 80_000, 96_000, 128_000)
    cloning = [sac.bc_weight * demo.teacher_scale(s) for s in steps]
    experts = [
        int(spread_envs(round(demo.fraction * loop.num_envs * demo.teacher_scale(s)), (16, 16)).sum()) for s in steps
    ]
    anchor = [sac.anchor_weight * demo.anchor_scale(s) for s in steps]
    assert cloning == [2.0, 2.0, 1.0, 0.0, 0.0, 0.0]
    assert experts == [8, 8, 4, 0, 0, 0]
    assert anchor[:4] == [0.0, 0.0, 1.0, 2.0]
    assert anchor[4:] == [2.0, 2.0]  # the anchor holds to the end
    assert loop.total_env_steps == 128_000 and loop.eval_seed != 1_000_003
