"""DAgger and the ``python -m baselines.imitate`` CLI end to end, on the real environment
with a cheap deterministic scripted expert (no NMPC) and short episodes."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest
from experts.scripted import ScriptedPolicy
from script_loader import load_script

import uvms_env
from baselines.imitation.cli import main
from baselines.imitation.dataset import read_dataset
from baselines.imitation.labelled_rollouts import rollouts

pytest.importorskip("torch")
pytest.importorskip("minari")

STEPS = 12


class Constant:
    """A learner unlike the expert: the same push every step."""

    def __init__(self, spec=None) -> None:
        self.stats: dict = {}

    def reset(self) -> None:
        pass

    def act(self, obs: np.ndarray) -> np.ndarray:
        return np.array([0.4, -0.3, 0.2, 0.1, 0.3, -0.3, 0.2, -0.2], dtype=np.float32)


def _env(seed: int):
    return uvms_env.parallel_env(
        scenario="short", seed=seed, max_cycles=STEPS, internal_wrench_every=0
    )


def _replay(seed: int, policy) -> list[dict[str, np.ndarray]]:
    """Observations of an episode in which every robot executes ``policy``."""
    env = _env(seed)
    obs, _ = env.reset(seed=seed)
    seen = [obs]
    while env.agents:
        obs, *_ = env.step({a: policy.act(obs[a]) for a in env.agents})
        seen.append(obs)
    return seen


def test_dagger_iteration_relabels_learner_visited_states():
    seed = 7
    streams, metrics = rollouts(
        _env, ScriptedPolicy, 1, seed, learner=Constant, beta=0.0, progress=False
    )
    assert len(streams) == 2 and len(metrics) == 1 and metrics[0]
    learner_obs = _replay(seed, Constant())
    expert_obs = _replay(seed, ScriptedPolicy())
    expert = ScriptedPolicy()
    for i, s in enumerate(streams):
        agent = f"uvms_{i}"
        assert len(s.actions) == STEPS and len(s.observations) == STEPS + 1
        assert all(s.learner_acted)
        recorded = np.stack(s.observations)
        # the visited states are the ones the LEARNER's actions produced ...
        assert np.array_equal(recorded, np.stack([o[agent] for o in learner_obs]))
        # ... not the expert's (so the test can tell them apart)
        assert not np.allclose(recorded[-1], expert_obs[-1][agent], atol=1e-3)
        # and every label is the expert's action in the visited state
        for o, a in zip(s.observations[:-1], s.actions, strict=True):
            assert np.array_equal(a, expert.act(o))


def test_beta_one_lets_the_expert_drive():
    streams, _ = rollouts(_env, ScriptedPolicy, 1, 3, learner=Constant, beta=1.0, progress=False)
    expert_obs = _replay(3, ScriptedPolicy())
    assert not any(streams[0].learner_acted)
    assert np.array_equal(np.stack(streams[0].observations), [o["uvms_0"] for o in expert_obs])


def test_gate_lets_the_learner_act_only_near_the_expert():
    seed = 9
    wide, _ = rollouts(_env, ScriptedPolicy, 1, seed, learner=Constant, beta=0.0, gate=2.0,
                       progress=False)  # fmt: skip
    assert all(all(s.learner_acted) for s in wide)  # actions differ by < 2 always
    shut, _ = rollouts(_env, ScriptedPolicy, 1, seed, learner=Constant, beta=0.0, gate=0.05,
                       progress=False)  # fmt: skip
    # Constant differs from the scripted (arms idle) action by >= 0.2 in the arm inputs,
    # so the expert drives throughout: the same states as a plain demonstration
    assert not any(any(s.learner_acted) for s in shut)
    expert_obs = _replay(seed, ScriptedPolicy())
    assert np.array_equal(np.stack(shut[0].observations), [o["uvms_0"] for o in expert_obs])


class Recording(ScriptedPolicy):
    """The scripted expert, remembering what its ``executed`` hook was told."""

    def __init__(self, spec=None) -> None:
        super().__init__(spec)
        self.told: list[np.ndarray] = []

    def executed(self, action: np.ndarray) -> None:
        self.told.append(np.array(action))


def test_noise_perturbs_the_executed_action_but_not_the_label():
    seed, noise = 5, 0.2
    made: list[Recording] = []

    def expert(spec):
        made.append(Recording(spec))
        return made[-1]

    streams, _ = rollouts(_env, expert, 1, seed, noise=noise, progress=False)
    clean = ScriptedPolicy()
    for s, policy in zip(streams, made, strict=True):
        assert not any(s.learner_acted)
        # labels: the clean expert action in each visited state
        for o, a in zip(s.observations[:-1], s.actions, strict=True):
            assert np.array_equal(a, clean.act(o))
        # the expert was told every perturbed input, each within the saturation
        told = np.stack(policy.told)
        assert told.shape == (STEPS, 8) and np.all(np.abs(told) <= 1)
        diff = told - np.stack(s.actions)
        assert 0.5 * noise < diff.std() < 1.5 * noise
    # the visited states are the perturbed ones, not the clean expert's
    expert_obs = _replay(seed, ScriptedPolicy())
    assert not np.allclose(streams[0].observations[-1], expert_obs[-1]["uvms_0"], atol=1e-4)
    with pytest.raises(ValueError, match="noise"):
        rollouts(_env, ScriptedPolicy, 1, seed, noise=-0.1, progress=False)


def test_cli_collect_bc_dagger_evaluate(tmp_path):
    from baselines.evaluation.runner import evaluate

    expert = "experts.scripted:expert"
    data = tmp_path / "data" / "tiny"
    main(["collect", "--scenario", "short", "--episodes", "1", "--max-cycles", str(STEPS),
          "--expert", expert, "--out", str(data)])  # fmt: skip
    obs, act, episodes = read_dataset(data.parent, data.name)
    assert len(episodes) == 2 and obs.shape == (2 * STEPS, 79) and act.shape == (2 * STEPS, 8)
    assert np.array_equal(episodes[0].infos["expert_iterations"][1:], np.ones(STEPS))
    noisy = tmp_path / "data" / "noisy"
    main(["collect", "--scenario", "short", "--episodes", "1", "--max-cycles", str(STEPS),
          "--expert", expert, "--noise", "0.1", "--out", str(noisy)])  # fmt: skip
    obs_n, _, _ = read_dataset(noisy.parent, noisy.name)
    assert obs_n.shape == (2 * STEPS, 79) and not np.allclose(obs_n[-1], obs[-1], atol=1e-4)

    bc_out, dagger_out, ff_out = tmp_path / "bc", tmp_path / "dagger", tmp_path / "bc_ff"
    main(["bc", "--data", str(data), "--epochs", "2", "--hidden", "16", "16",
          "--out", str(bc_out)])  # fmt: skip
    # the steady-input features read the object that collect recorded per stream
    assert np.all(episodes[0].infos["object_key"] == 0.0)  # short carries the bar
    main(["bc", "--data", str(data), "--epochs", "2", "--hidden", "16", "--features",
          "features", "--out", str(ff_out)])  # fmt: skip
    main(["dagger", "--data", str(data), "--scenario", "short:1", "--iterations", "1",
          "--episodes-per-iteration", "3", "--max-cycles", str(STEPS), "--epochs", "2",
          "--hidden", "16", "16", "--expert", expert, "--save-data", "--lr-schedule", "cosine",
          "--loss-scale", "std", "--out", str(dagger_out)])  # fmt: skip
    for out, log in ((bc_out, "bc_loss.csv"), (dagger_out, "dagger_loss.csv")):
        assert (out / "policy.pt").exists() and (out / "train.json").exists()
        rows = list(csv.DictReader(open(out / log)))
        assert rows and all(np.isfinite(float(r["train_loss"])) for r in rows)
    info = json.loads((dagger_out / "train.json").read_text())
    # demonstrations + one relabelled rollout ("short:1" overrides the 3 per iteration)
    assert info["samples"] == 4 * STEPS
    assert info["history"][1]["rollouts_short"]["episodes"] == 1
    assert info["history"][1]["beta"] == 0.5
    assert info["loss_scale"] == "std" and info["lr_schedule"] == "cosine"
    assert len(info["history"][1]["learner_state_rmse"]) == 8  # per action component
    _, _, eps = read_dataset(dagger_out / "data", "iter_1")
    assert len(eps) == 2

    rows = evaluate(
        [f"bc:{bc_out}", f"dagger:{dagger_out}", f"bc:{ff_out}"],
        ["short"],
        episodes=1,
        seed=0,
        workers=1,
        max_cycles=STEPS,
        progress=False,
    )
    assert [r["error"] for r in rows] == ["", "", ""]
    assert all(r["episode_steps"] == STEPS for r in rows)
    assert all(r["policy_time_ms_median"] < 5 for r in rows)


def test_safe_distillation_labels_are_the_filters_correction_of_the_network(tmp_path):
    """``dagger --init dagger:pretrained --expert self+filter``: each label is the safety
    filter's answer to the current network's own action, per robot, from its own
    observations; the network is fine-tuned, its input normalization kept."""
    pytest.importorskip("daqp")
    from baselines.loaders.clone_policy import ClonedPolicy
    from baselines.networks.mlp import MLPPolicyNet
    from nmpc_expert import make_filter
    from uvms_env.policy import AgentSpec

    out = tmp_path / "distill"
    main(["dagger", "--init", "dagger:pretrained", "--expert", "self+filter", "--scenario",
          "short:1", "--iterations", "1", "--beta", "0", "--max-cycles", str(STEPS), "--epochs",
          "1", "--save-data", "--out", str(out)])  # fmt: skip
    info = json.loads((out / "train.json").read_text())
    assert info["init"] == "dagger:pretrained" and info["expert"] == "self+filter"
    assert info["samples"] == 2 * STEPS  # no demonstrations: the rollout alone
    start = MLPPolicyNet.load(ClonedPolicy.locate("dagger", None))
    tuned = MLPPolicyNet.load(out / "policy.pt")
    assert np.array_equal(tuned.obs_mean.numpy(), start.obs_mean.numpy())
    assert not np.allclose(tuned.numpy_weights()[0][0], start.numpy_weights()[0][0])

    _, _, eps = read_dataset(out / "data", "iter_1")
    seed = info["seed"] + 1000  # iteration 1, first scenario
    env = uvms_env.parallel_env(scenario="short", seed=seed, internal_wrench_every=0)
    env.reset(seed=seed)
    intervened = 0
    for i, ep in enumerate(eps):
        spec = AgentSpec.from_scenario(env.scenario, i)
        path = out / "iter_0" / "policy.pt"
        teacher = make_filter(lambda s, p=path: ClonedPolicy(s, p))(spec)
        learner = ClonedPolicy(spec, path)
        teacher.reset()
        for o, label in zip(ep.observations[:-1], ep.actions, strict=True):
            proposal = learner.act(o)
            np.testing.assert_allclose(teacher.act(o), label, atol=1e-4)
            teacher.executed(proposal)  # the learner drove (beta 0)
            intervened += int(np.max(np.abs(label - np.clip(proposal, -1, 1))) > 1e-3)
    assert intervened > 0  # the labels are corrections, not the proposals


def test_history_probe_aligns_each_stream_with_its_own_past(tmp_path):
    """``history_probe``: the previous-action inputs of step t are the label of step t-1
    of the same robot's stream (a_ss at its first step), never another stream's."""
    probe = load_script("history_probe")
    VARIANTS, history_inputs = probe.VARIANTS, probe.history_inputs

    data = tmp_path / "data" / "tiny"
    main(["collect", "--scenario", "short", "--episodes", "2", "--max-cycles", str(STEPS),
          "--expert", "experts.scripted:expert", "--out", str(data)])  # fmt: skip
    inputs, labels, held = history_inputs(data)
    assert set(inputs) == set(VARIANTS) and len(labels) == 4 * STEPS == len(held)
    current, with_action = inputs["current"], inputs["+ previous action"]
    assert np.array_equal(with_action[:, 8:], current)  # a_ss stays last
    for start in range(0, 4 * STEPS, STEPS):  # one stream per robot and episode
        rows = slice(start, start + STEPS)
        prev = with_action[rows, :8]
        assert np.array_equal(prev[1:], labels[rows][:-1])
        assert np.array_equal(prev[0], np.clip(current[start, -8:], -1, 1))
    assert held[: 2 * STEPS].all() and not held[2 * STEPS :].any()  # held out by episode


class _RecordingTeam:
    """A team policy that pushes each robot by its index and records what it is told."""

    information = "full"

    def __init__(self, scenario) -> None:
        self.n = scenario.n_agents
        self.stats: dict = {}
        self.states: list[np.ndarray] = []
        self.applied: list[np.ndarray] = []

    def reset(self) -> None:
        self.states.clear()

    def act(self, state: np.ndarray) -> np.ndarray:
        self.states.append(np.array(state))
        return self.decision(state)

    def decision(self, state: np.ndarray) -> np.ndarray:
        return np.tile(0.1 * (1 + np.arange(self.n))[:, None], (1, 8)) * np.sign(state[0] + 0.5)

    def executed(self, actions: np.ndarray) -> None:
        self.applied.append(np.array(actions))


def test_team_teacher_labels_each_robot_with_its_row_and_hears_the_students():
    """A team teacher decides once per period from the global state; robot i's label is
    row i; where the students acted, the team hears their applied inputs before its next
    decision."""
    from uvms_env.team_policy import TeamPolicyFactory

    built: list[_RecordingTeam] = []

    def build(scenario) -> _RecordingTeam:
        built.append(_RecordingTeam(scenario))
        return built[-1]

    streams, _ = rollouts(
        _env, TeamPolicyFactory(build, "recording"), 1, 5, learner=Constant, beta=0.0,
        progress=False,
    )  # fmt: skip
    (team,) = built
    assert len(team.states) == STEPS  # one team decision per period, not one per robot
    for i, s in enumerate(streams):
        for label, state in zip(s.actions, team.states, strict=True):
            assert np.allclose(label, team.decision(state)[i])
    # every period after the first, the students' (Constant's) inputs, one row per robot
    assert len(team.applied) == STEPS - 1
    assert all(np.allclose(a, np.tile(Constant().act(None), (2, 1))) for a in team.applied)


def test_the_centralized_bound_teaches_the_team_it_would_drive():
    """``nmpc:central`` as the DAgger teacher with beta = 1: the labels are the reference's own
    episode, row by row (the same team decisions ``play_team`` makes)."""
    pytest.importorskip("daqp")
    from baselines.loaders.sources import PolicySource
    from uvms_env.episode import play_team

    seed = 3
    source = PolicySource.parse("nmpc:central")
    streams, _ = rollouts(_env, source.team_factory(seed), 1, seed, progress=False)
    decisions: list[dict[str, np.ndarray]] = []
    play_team(_env(seed), source.team_factory(seed), seed,
              on_step=lambda step: decisions.append(dict(step.actions)))  # fmt: skip
    assert len(decisions) == STEPS
    for i, s in enumerate(streams):
        assert np.allclose(np.stack(s.actions), [d[f"uvms_{i}"] for d in decisions], atol=1e-6)


def test_a_student_from_the_bound_end_to_end(tmp_path):
    """The students' recipe at a tiny budget: demonstrations and DAgger labelled by
    ``nmpc:central`` on memory features, then the run folder evaluated as ``student:PATH``
    (the clone's loader, the robot's memory inside it)."""
    pytest.importorskip("daqp")
    from baselines.evaluation.runner import evaluate

    data, out = tmp_path / "data" / "central", tmp_path / "student"
    main(["collect", "--scenario", "short", "--episodes", "1", "--max-cycles", str(STEPS),
          "--expert", "nmpc:central", "--noise", "0.05", "--out", str(data)])  # fmt: skip
    main(["dagger", "--data", str(data), "--scenario", "short:1", "--iterations", "1",
          "--max-cycles", str(STEPS), "--epochs", "2", "--hidden", "16", "--features",
          "memory", "--expert", "nmpc:central", "--out", str(out)])  # fmt: skip
    info = json.loads((out / "train.json").read_text())
    assert info["expert"] == "nmpc:central" and info["features"] == "memory"
    assert info["samples"] == 4 * STEPS  # two robots' demonstrations + one relabelled rollout
    (row,) = evaluate([f"student:{out}"], ["short"], episodes=1, seed=0, workers=1,
                      max_cycles=STEPS, progress=False)  # fmt: skip
    assert row["error"] == "" and row["episode_steps"] == STEPS
