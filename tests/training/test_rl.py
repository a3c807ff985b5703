"""RL baselines: the SB3 trainer's VecEnv stack, training end to end, and the committed
pretrained models reproducing their recorded evaluation."""

from __future__ import annotations

import csv
import io
import json

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")

from baselines.evaluation.runner import evaluate
from baselines.loaders.saved import PRETRAINED
from baselines.rl.sb3_trainer import find_resume, make_vec_env
from baselines.runs import RunSettings, training_env_options
from baselines.train import main, train
from uvms_env.task.rules import EPISODE_ENDS

SEED = 7


def test_train_save_resume_evaluate(tmp_path):
    out = tmp_path / "ppo"
    hp = {"n_steps": 32, "batch_size": 64, "n_epochs": 1}

    def settings(budget: int, **kw) -> RunSettings:
        return RunSettings(
            "short",
            {"max_cycles": 24},
            budget,
            2,
            0,
            out,
            record_eval=False,
            hyperparameters=hp,
            progress=False,
            **kw,
        )

    train(
        "sb3",
        "ppo",
        settings(128, eval_every=128, eval_episodes=1, checkpoint_every=128, eval_max_cycles=40),
    )
    for name in ("model.zip", "vecnormalize.pkl", "config.json", "progress.csv"):
        assert (out / name).exists(), name
    assert (out / "evaluations.csv").read_text().count("\n") == 2  # header + one evaluation
    assert list((out / "checkpoints").glob("rl_model_*_steps.zip"))
    assert any(out.glob("events.out.tfevents*"))
    # Resume from the newest checkpoint to 256 steps in all.
    model, norm, _ = find_resume(out / "checkpoints" / "rl_model_128_steps.zip")
    assert norm.name == "rl_model_vecnormalize_128_steps.pkl"
    train("sb3", "ppo", settings(256, resume=model))
    config = json.loads((out / "config.json").read_text())
    assert config["robot_steps"] == 256 and config["resumes"] == 1
    progress = (out / "progress.csv").read_text().splitlines()
    assert [int(line.split(",")[1]) for line in progress[1:]] == [128, 256]  # appended
    # how the iteration's training episodes ended (a 24-period cap: each copy's first end
    # in every 32-period iteration), and the objective: the return itself without a cost
    last = list(csv.DictReader(io.StringIO("\n".join(progress))))[-1]
    ends = {e: int(last[f"ends_{e}"]) for e in EPISODE_ENDS}
    assert int(last["episodes"]) == sum(ends.values()) == ends["max_cycles"] >= 1
    assert float(last["episode_objective_mean"]) == float(last["episode_return_mean"])
    rows = evaluate([f"ppo:{out}"], ["short"], 1, 0, 1, max_cycles=20, progress=False)
    assert rows[0]["error"] == "" and rows[0]["episode_steps"] == 20


def test_make_vec_env_paths():
    from uvms_env.vector.sb3 import VectorVecEnv

    vector = make_vec_env("short", 3, 0, [training_env_options({"max_cycles": 10})])
    assert isinstance(vector.venv, VectorVecEnv) and vector.num_envs == 6
    inner = vector.venv.vector_env
    assert (inner.dtype, inner.geometry_pool, inner.threads) == ("float32", 1024, 1)
    assert inner.internal_wrench_every == 0  # the training defaults reach the batched env
    paper = make_vec_env("paper", 1, 0, [{}], dtype="float64", geometry_pool=1024)
    assert paper.venv.vector_env.geometry_pool is None  # a fixed geometry: no pool
    for venv in (vector, paper):
        assert venv.reset().shape == (venv.num_envs, 79)
        venv.close()
    with pytest.raises(ValueError, match="dtype"):
        make_vec_env("short", 1, 0, [{}], dtype="float16")


def test_cli_records_the_env_settings(tmp_path):
    out = tmp_path / "run"
    argv = ["--algo", "ppo", "--robot-steps", "64", "--num-envs", "2", "--out", str(out)]
    argv += ["--dtype", "float64", "--geometry-pool", "8"]
    argv += ["--env-option", "max_cycles=10", "--no-progress", "--checkpoint-every", "1000"]
    argv += ["--hp", "n_steps=16", "--hp", "batch_size=32", "--hp", "n_epochs=1"]
    argv += ["--hp", 'policy_kwargs={"log_std_init": -2.0}']
    main(argv)
    config = json.loads((out / "config.json").read_text())
    own = config["library_settings"]
    assert own["policy_kwargs"] == {"log_std_init": -2.0}  # added to, not replacing, NET
    from stable_baselines3 import PPO

    log_std = PPO.load(out / "model.zip", device="cpu").policy.log_std.detach().numpy()
    assert log_std.shape == (8,) and np.all(np.abs(log_std + 2.0) < 0.05)  # moved little
    expected = {"dtype": "float64", "geometry_pool": 8, "env_threads": 1}
    assert {key: own[key] for key in expected} == expected
    assert config["robot_steps"] == 64 and own["robot_sub_envs"] == 4
    assert len(config["eval"]["episodes"]) == 2  # evaluated on single envs after training


COMMITTED = [
    ("ppo", "ppo"),  # the DAgger clone fine-tuned over the ladder's distribution
    ("ppo", "ppo_scratch"),  # MAPPO from scratch over the distribution (its central critic)
]


def test_every_committed_sb3_model_is_replayed():
    """A model committed without a replay below would go unchecked."""
    folders = {p.name for p in PRETRAINED.iterdir() if (p / "model.zip").is_file()}
    assert folders == {name for _, name in COMMITTED}


@pytest.mark.parametrize(("algo", "name"), COMMITTED)
def test_pretrained_reproduces_recorded_evaluation(algo, name):
    """Every committed SB3 model loads and replays the evaluation its config.json
    recorded (written by the trainer of its day: the loaders read that layout)."""
    folder = PRETRAINED / name
    source = f"{algo}:pretrained" if name == algo else f"{algo}:{folder}"
    for file in ("model.zip", "vecnormalize.pkl", "config.json"):
        assert (folder / file).stat().st_size < 1_000_000, file
    recorded = json.loads((folder / "config.json").read_text())["eval"]
    n = len(recorded["episodes"])
    runs = [
        evaluate(
            [source],
            [recorded["scenario"]],
            n,
            recorded["seed"],
            1,
            recorded.get("overrides"),
            recorded.get("max_cycles"),
            progress=False,
        )
        for _ in range(2)
    ]
    for first, second, rec in zip(*runs, recorded["episodes"], strict=True):
        assert first["error"] == ""
        assert first["return"] == second["return"]  # deterministic, bit for bit
        assert first["episode_steps"] == second["episode_steps"]
        assert first["seed"] == rec["seed"]
        assert bool(first["success"]) == rec["success"]
        # bit for bit only on the machine that recorded it: the compiled physics is built
        # with -march=native, and another CPU's rounding (seen: AVX-512 vs not; another
        # BLAS kernel) grows over hundreds of closed-loop steps, here by up to 1.5% of the
        # return; the episode's length moves with it
        assert first["episode_steps"] == pytest.approx(rec["episode_steps"], rel=0.05)
        assert first["return"] == pytest.approx(rec["return"], rel=0.05)
