"""The loaded-policy base (``baselines.loaders.saved``) and the registry: one rule finds
every saved policy, one cache loads each once per file stamp, one run record gives the
priors and the channel, and every ``--policy`` name of a saved network has its loader."""

from __future__ import annotations

import json
import os

import pytest

from baselines import registry
from baselines.loaders import saved as loaded_policy
from baselines.loaders.clone_policy import ClonedPolicy
from baselines.loaders.saved import PRETRAINED, LoadedPolicy, load_once, run_record
from baselines.loaders.sb3_policy import SB3Policy


def test_one_rule_finds_the_committed_models_a_run_folder_and_a_file(tmp_path):
    assert SB3Policy.locate("ppo", "pretrained") == PRETRAINED / "ppo" / "model.zip"
    assert ClonedPolicy.locate("dagger", None) == PRETRAINED / "dagger" / "policy.pt"
    (tmp_path / "model.zip").write_bytes(b"")
    assert SB3Policy.locate("ppo", str(tmp_path)) == tmp_path / "model.zip"
    named = tmp_path / "clone_7.pt"
    named.write_bytes(b"")
    assert ClonedPolicy.locate("bc", str(named)) == named  # a file of its kind, any name
    with pytest.raises(ValueError, match=r"no SB3 model at .*pretrained/sac"):
        SB3Policy.locate("sac", None)  # the one default: a committed model
    with pytest.raises(ValueError, match="no SB3 model"):
        SB3Policy.locate("ppo", str(tmp_path / "elsewhere"))


def test_a_committed_variant_is_named_by_a_bare_word(tmp_path, monkeypatch):
    """``student:expert`` is ``pretrained/student_expert``; a word naming no variant is a
    path, as before."""
    assert ClonedPolicy.locate("student", "pretrained") == PRETRAINED / "student" / "policy.pt"
    assert ClonedPolicy.locate("student", "expert") == PRETRAINED / "student_expert" / "policy.pt"
    monkeypatch.setattr(loaded_policy, "PRETRAINED", tmp_path)
    (tmp_path / "clone_teacher").mkdir()
    (tmp_path / "clone_teacher" / "policy.pt").write_bytes(b"")
    assert ClonedPolicy.locate("clone", "teacher") == tmp_path / "clone_teacher" / "policy.pt"
    with pytest.raises(ValueError, match="no cloned policy at other"):
        ClonedPolicy.locate("clone", "other")


def test_a_network_is_loaded_once_per_file_stamp(tmp_path):
    calls = []

    def load(path, scale):
        calls.append(path)
        return scale * len(path.read_text())

    saved = tmp_path / "net.txt"
    saved.write_text("ab")
    assert load_once(load, saved, (), 10) == load_once(load, saved, (), 10) == 20
    assert len(calls) == 1
    saved.write_text("abc")  # re-saved (a training run's snapshot): loaded again
    os.utime(saved, ns=(1, 1))
    assert load_once(load, saved, (), 10) == 30 and len(calls) == 2


def test_the_run_record_is_the_nearest_config(tmp_path):
    run = tmp_path / "run"
    (run / "checkpoints" / "robot_steps_64").mkdir(parents=True)
    options = {"action_mode": "residual", "observation_mode": "features", "comm": "atm900"}
    (run / "config.json").write_text(json.dumps({"overrides": {}, "env_options": options}))
    priors, comm = run_record(run / "checkpoints" / "robot_steps_64" / "actor.pt")
    assert priors.action_mode == "residual" and priors.observation_mode == "features"
    assert comm is not None
    priors, comm = run_record(tmp_path / "elsewhere" / "actor.pt")
    assert priors.plain and comm is None


def test_every_saved_policy_name_has_a_loaded_policy_loader():
    for name in registry.LOADERS:
        if name == "rllib":
            pytest.importorskip("ray")
        assert issubclass(registry.loader(name), LoadedPolicy), name
    for lib in registry.LIBRARIES.values():  # what each library saves, a loader reads
        assert all((lib.policy or algo) in registry.LOADERS for algo in lib.algos), lib
    assert registry.policy_spec("sb3", "sac", PRETRAINED) == f"sac:{PRETRAINED}"
    assert registry.policy_spec("benchmarl", "mappo", PRETRAINED) == f"benchmarl:{PRETRAINED}"


def test_the_robots_of_a_committed_model_share_one_loaded_network():
    from baselines.loaders.sources import PolicySource
    from uvms_env.policy import AgentSpec
    from uvms_env.scenarios import make

    scenario = make("paper")
    for text in ("ppo:pretrained", "dagger:pretrained"):
        factory = PolicySource.parse(text).factory(0)
        first, second = (factory(AgentSpec.from_scenario(scenario, i)) for i in range(2))
        net = "model" if text.startswith("ppo") else "net"
        assert getattr(first, net) is getattr(second, net), text
    assert loaded_policy.PRIOR_OPTIONS[:2] == ("action_mode", "observation_mode")


def test_a_batch_of_robots_decides_as_each_robot_alone():
    """``decide_many`` (one forward for many robots) against ``decide`` row by row, for
    SB3's ``predict`` path (the loader's own batch) and the base's default; and a robot's
    ``batch_key`` is shared by its teammates and by the same model on another episode."""
    import numpy as np

    from baselines.loaders.sources import PriorPolicy
    from uvms_env.policy import AgentSpec
    from uvms_env.scenarios import make

    scenario = make("random", n_agents=3, seed=5)
    specs = [AgentSpec.from_scenario(scenario, i) for i in range(3)]
    policies = [SB3Policy(s, "ppo", PRETRAINED / "ppo_scratch", compiled=False) for s in specs]
    width = policies[0].priors.observation_size  # what decide reads: the priors' features
    x = np.random.default_rng(0).normal(size=(7, width)).astype(np.float32)
    rows = np.stack([policies[0].decide(row) for row in x])
    np.testing.assert_allclose(policies[0].decide_many(x), rows, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(LoadedPolicy.decide_many(policies[0], x), rows, atol=0)
    assert len({p.batch_key() for p in policies}) == 1
    other = SB3Policy(
        AgentSpec.from_scenario(make("random", n_agents=3, seed=6), 1),
        "ppo",
        PRETRAINED / "ppo_scratch",
        compiled=False,
    )
    assert other.batch_key() == policies[0].batch_key()
    assert PriorPolicy(specs[0]).batch_key() != policies[0].batch_key()


def test_the_committed_from_scratch_model_is_a_rung_and_acts_on_a_bar():
    """``ppo:scratch`` (MAPPO from scratch over rings and bars: its critic reads the team's
    padded state, its actor one robot's observation) is found by its bare word, sits on
    the ladder alone and in the filter, and decides bounded inputs for each robot of a
    three-robot bar, from that robot's observation only."""

    import uvms_env
    from baselines.ladder import LADDER

    assert SB3Policy.locate("ppo", "scratch") == PRETRAINED / "ppo_scratch" / "model.zip"
    assert {"ppo:scratch", "ppo:scratch+filter"} <= set(LADDER)
    env = uvms_env.parallel_env("random", n_agents=3, object="bar", course="mixed")
    _acts_within_bounds(env, "ppo:scratch", seed=4)


def test_the_clone_over_rings_and_bars_acts_on_the_papers_team():
    """``dagger:bars`` (DAgger over the random family's rings and bars, the paper held out)
    is found by its bare word and decides bounded inputs for both robots of the paper's
    bar from each one's own observation."""
    import uvms_env

    assert ClonedPolicy.locate("dagger", "bars") == PRETRAINED / "dagger_bars" / "policy.pt"
    card = json.loads((PRETRAINED / "dagger_bars" / "info.json").read_text())
    assert "--scenario paper" not in " ".join(card["commands"])  # never trained on it
    _acts_within_bounds(uvms_env.parallel_env("paper"), "dagger:bars", seed=3)


def test_the_mixed_clone_is_a_rung_trained_without_the_paper_and_acts_on_its_team():
    """``dagger:mix`` (DAgger over rings and bars with more two-robot bars, the paper held
    out) is found by its bare word, sits on the ladder alone and in the filter, records
    the two-robot bar data it joined to the distribution's, and decides bounded inputs
    on the paper's team and on a random ring."""
    import uvms_env
    from baselines.ladder import LADDER

    assert ClonedPolicy.locate("dagger", "mix") == PRETRAINED / "dagger_mix" / "policy.pt"
    assert {"dagger:mix", "dagger:mix+filter"} <= set(LADDER)
    card = json.loads((PRETRAINED / "dagger_mix" / "info.json").read_text())
    commands = " ".join(card["commands"])
    assert "--scenario paper" not in commands  # never trained on it
    assert "--data runs/data/distbar_n05 --data runs/data/bar2_turns_n05" in commands
    # five training seeds (0, 100000, ...), as the docs' tables say; the rule kept seed 0
    assert card["committed_seed"] == "0" and card["trained_on"]["seeds"] == 5
    assert [s["seed"] for s in card["seeds"].values()] == [100000 * k for k in range(5)]
    _acts_within_bounds(uvms_env.parallel_env("paper"), "dagger:mix", seed=6)
    # three robots with noisy sensors: the kernels other tests compile (tests/robot)
    ring = uvms_env.parallel_env("random", n_agents=3, seed=2, sensor_noise=1.0)
    _acts_within_bounds(ring, "dagger:mix", seed=7)


def test_the_pair_specialist_continues_the_bar_clone_and_acts_on_the_papers_team():
    """``dagger:bar2`` (``dagger:bars`` continued on two robots carrying a bar, the paper
    held out) is found by its bare word, records the model it started from and a training
    distribution of two-robot bars only, and decides bounded inputs on the paper's team."""
    import uvms_env

    assert ClonedPolicy.locate("dagger", "bar2") == PRETRAINED / "dagger_bar2" / "policy.pt"
    card = json.loads((PRETRAINED / "dagger_bar2" / "info.json").read_text())
    commands = " ".join(card["commands"])
    assert "--init dagger:bars" in commands and "--scenario paper" not in commands
    assert "--n-agents 2 --object bar" in commands
    _acts_within_bounds(uvms_env.parallel_env("paper"), "dagger:bar2", seed=5)


def _acts_within_bounds(env, policy: str, seed: int) -> None:
    """Five steps of ``policy`` on ``env``: every robot's action (8,) within [-1, 1], from
    its own observation, and the episode still running."""
    import numpy as np

    from baselines.loaders.sources import PolicySource
    from uvms_env.episode import build_policies

    obs, _ = env.reset(seed=seed)
    policies = build_policies(env, PolicySource.parse(policy).factory(0))
    for _ in range(5):
        actions = {agent: policies[agent].act(obs[agent]) for agent in env.agents}
        for action in actions.values():
            assert action.shape == (8,) and np.all(np.abs(action) <= 1.0)
        obs, _, terminated, truncated, _ = env.step(actions)
        assert not any(terminated.values()) and not any(truncated.values())


def test_the_committed_runs_cards_state_the_settings_their_config_records():
    """A model card's ``settings`` are what its run's config.json recorded (the trainer's
    hyperparameters as they ran, not a library's defaults), and say what it trained on."""
    import json

    from baselines.loaders.saved import PRETRAINED

    checked = 0
    for config_file in sorted(PRETRAINED.glob("*/config.json")):
        card = json.loads((config_file.parent / "info.json").read_text())
        config = json.loads(config_file.read_text())
        ran = config.get("library_settings") or config["engine_settings"]  # the older key
        settings = card["settings"]
        assert settings["num_envs"] == config["num_envs"], config_file
        for key in ("hyperparameters", "policy_kwargs", "net_arch"):
            assert settings[key] == ran[key], (config_file, key)
        assert set(card["trained_on"]) == {"paper", "bars", "seeds", "budget"}
        checked += 1
    assert checked >= 2
