"""PPO with TorchRL over the TorchRL view of ``VectorEnv``, every tensor on one device.

    python -m baselines.train --library torchrl --algo ppo --scenario short --num-envs 4096 \\
        --backend cuda --device 0 --robot-steps 50000000 --out runs/torchrl_ppo

Rollouts, advantages and updates never copy through the host. Settings follow the SB3
trainer (``HYPERPARAMETERS``); the actor keeps the observation statistics, so the saved
``actor.pt`` normalizes itself; ``trainer.pt`` holds what ``--resume`` needs.
Reference: docs/rl.md, "The torchrl trainer".

May import: numpy, torch, tensordict and torchrl (inside the training functions),
``baselines.runs``, ``baselines.lagrangian``, ``baselines.registry``, ``baselines.command_line``
(the flags' types), ``baselines.loaders.torchrl_policy`` (the actor's network) and ``uvms_env``.
"""

from __future__ import annotations

import argparse
import math
import os
import time
import warnings
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np
import torch
from torch import nn

from baselines.command_line import positive_int
from baselines.lagrangian import Lagrangian
from baselines.loaders.torchrl_policy import (
    ACTOR_FILE,
    CLIP_OBSERVATION,
    ActorNet,
    RunningNorm,
    mlp,
    save_actor,
)
from baselines.registry import LIBRARIES
from baselines.runs import DTYPES, Run, add_step_arguments, seeded_pool
from uvms_env.vector.batched_simulator import BACKENDS

ALGOS = LIBRARIES["torchrl"].algos
HYPERPARAMETERS: dict[str, Any] = {
    # the sb3 trainer's regime: short rollouts of many copies, few epochs, large minibatches
    "rollout_steps": 32,  # per env copy and iteration (SB3's n_steps)
    "minibatches": 4,  # per epoch, over the rollout's robot samples
    "epochs": 4,
    "lr": 3e-4,
    "gamma": 0.99,
    "gae_lambda": 0.95,
    "clip_epsilon": 0.2,
    "entropy_coef": 0.0,
    "critic_coef": 0.5,
    "max_grad_norm": 0.5,
    "log_std_init": -1.0,
    "hidden": [64, 64],
    "normalize_observation": True,
    "scale_reward": True,
}
TRAINER_FILE = "trainer.pt"
# As the SB3 trainer: a seeded family's episodes take the bank's first 1,024 geometries.
DEFAULTS: dict[str, Any] = {"num_envs": 64, "geometry_pool": 1024}
SEVERAL_TEAM_SIZES = True  # one TorchRL env per team size, one shared policy


OPTIONS_NOTE = f"--hp KEY=JSON sets one of {', '.join(HYPERPARAMETERS)}"


def add_arguments(g: Any) -> None:
    """The TorchRL trainer's own options."""
    g.add_argument("--backend", choices=BACKENDS, default="cpu", help="the VectorEnv backend")
    g.add_argument(
        "--device",
        default=None,
        help="GPU index (default 0 with --backend cuda) or cpu: where the env's tensors, "
        "the networks and the updates live",
    )
    add_step_arguments(g)
    g.add_argument("--torch-threads", type=positive_int, default=1)


def check_options(settings: Any, algo: str, args: argparse.Namespace) -> None:
    """ValueError naming the option where this trainer cannot honour ``settings``
    (``baselines.runs.RunSettings``) or its own options ``args``: before any work."""
    if algo not in ALGOS:
        raise ValueError(f"torchrl trains {ALGOS}, not {algo!r}")
    if args.backend not in BACKENDS:
        raise ValueError(f"--backend must be one of {BACKENDS}, got {args.backend!r}")
    if args.dtype not in DTYPES:
        raise ValueError(f"--dtype must be one of {DTYPES}, got {args.dtype!r}")
    unknown = set(settings.hyperparameters) - set(HYPERPARAMETERS)
    if unknown:
        known = list(HYPERPARAMETERS)
        raise ValueError(f"--hp: unknown hyperparameters {sorted(unknown)}; known: {known}")
    if settings.cost is not None and len(settings.groups()) > 1:
        raise ValueError(
            "--cost with several team sizes: train it with --library sb3 (one multiplier "
            "over every robot), or give torchrl one team size"
        )
    parse_device(args.device, args.backend)


# -- networks ---------------------------------------------------------------------------------
class CriticNet(nn.Module):
    def __init__(self, observation_size: int, hidden: list[int], normalize: bool) -> None:
        super().__init__()
        self.norm = RunningNorm(observation_size) if normalize else nn.Identity()
        self.body = mlp(observation_size, hidden, 1)

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return self.body(self.norm(obs))


# -- training ---------------------------------------------------------------------------------
def parse_device(text: str | int | None, backend: str) -> str | int:
    """``--device``: a GPU index (int) or ``cpu``; default GPU 0 for the CUDA backend."""
    if text is None:
        return 0 if backend == "cuda" else "cpu"
    if isinstance(text, int) or str(text).isdigit():
        return int(text)
    if str(text).startswith("cuda:") and str(text)[5:].isdigit():
        return int(str(text)[5:])
    if text != "cpu":
        raise ValueError(f"--device must be a GPU index or 'cpu', got {text!r}")
    return "cpu"


def torch_device(device: str | int) -> torch.device:
    return torch.device("cpu") if device == "cpu" else torch.device("cuda", int(device))


def make_env(
    scenario: str,
    num_envs: int,
    backend: str,
    device: str | int,
    dtype: str,
    geometry_pool: int | None,
    env_threads: int | None,
    options: dict[str, Any],
):
    """The TorchRL env over one ``VectorEnv`` with the environment ``options`` (a group's:
    ``RunSettings.groups``) (``backend``, ``device``; seeded families: episodes on the first
    ``geometry_pool`` bank geometries), its tensors on ``device``."""
    from uvms_env.vector import VectorEnv
    from uvms_env.vector.torchrl_env import CoopTransportTorchRLEnv

    kwargs = dict(options)
    if geometry_pool is not None:
        kwargs["geometry_pool"] = geometry_pool
    if backend == "cuda":
        kwargs["device"] = device
    venv = VectorEnv(
        scenario, num_envs=num_envs, backend=backend, dtype=dtype, threads=env_threads, **kwargs
    )
    return CoopTransportTorchRLEnv(venv, device=torch_device(device))


def build_modules(env: Any, hp: dict[str, Any]) -> tuple[Any, Any, ActorNet, CriticNet]:
    """(actor, critic, actor net, critic net) on the env's device: TorchRL's
    ``ProbabilisticActor`` (TanhNormal on [-1, 1]) and ``ValueOperator`` over the group."""
    from tensordict.nn import TensorDictModule
    from torchrl.modules import ProbabilisticActor, TanhNormal, ValueOperator

    from uvms_env.vector.torchrl_env import GROUP

    size = env.observation_spec[GROUP, "observation"].shape[-1]
    act_size = env.full_action_spec[GROUP, "action"].shape[-1]  # 8, more with a channel
    actor_net = ActorNet(
        size, hp["hidden"], hp["log_std_init"], hp["normalize_observation"], act_size
    )
    critic_net = CriticNet(size, hp["hidden"], hp["normalize_observation"])
    actor_net, critic_net = actor_net.to(env.device), critic_net.to(env.device)
    params = TensorDictModule(
        actor_net, in_keys=[(GROUP, "observation")], out_keys=[(GROUP, "loc"), (GROUP, "scale")]
    )
    actor = ProbabilisticActor(
        params,
        in_keys=[(GROUP, "loc"), (GROUP, "scale")],
        out_keys=[(GROUP, "action")],
        spec=env.full_action_spec[GROUP, "action"],
        distribution_class=TanhNormal,
        distribution_kwargs={"low": -1.0, "high": 1.0},
        return_log_prob=True,
    )
    critic = ValueOperator(
        critic_net, in_keys=[(GROUP, "observation")], out_keys=[(GROUP, "state_value")]
    )
    return actor, critic, actor_net, critic_net


def ppo_loss(actor: Any, critic: Any, hp: dict[str, Any]) -> Any:
    """TorchRL's clipped PPO loss over the group's keys, with GAE as its value estimator."""
    from torchrl.objectives import ClipPPOLoss, ValueEstimators

    from uvms_env.vector.torchrl_env import GROUP

    loss = ClipPPOLoss(
        actor_network=actor,
        critic_network=critic,
        clip_epsilon=hp["clip_epsilon"],
        entropy_bonus=hp["entropy_coef"] > 0,
        entropy_coeff=hp["entropy_coef"],
        critic_coeff=hp["critic_coef"],
        loss_critic_type="l2",
        normalize_advantage=True,
    )
    loss.set_keys(
        reward=(GROUP, "reward"),
        action=(GROUP, "action"),
        value=(GROUP, "state_value"),
        done=(GROUP, "done"),
        terminated=(GROUP, "terminated"),
        advantage=(GROUP, "advantage"),
        value_target=(GROUP, "value_target"),
    )
    # The advantages are normalized over the minibatch's rows and robots together (one
    # shared policy), which TorchRL's multi-agent warning asks to confirm on every call.
    warnings.filterwarnings("ignore", "You requested advantage normalization", UserWarning)
    loss.make_value_estimator(ValueEstimators.GAE, gamma=hp["gamma"], lmbda=hp["gae_lambda"])
    return loss


class EpisodeTracker:
    """The team's episode returns and lengths (unscaled reward), and the running spread of
    the discounted return that scales the reward (VecNormalize's ``ret_rms``), carried
    across rollouts on the device."""

    def __init__(
        self, k: int, gamma: float, device: torch.device, ret_stats: RunningNorm | None = None
    ) -> None:
        self.gamma = gamma
        self.ret = torch.zeros(k, device=device)
        self.len = torch.zeros(k, device=device)
        self.discounted = torch.zeros(k, device=device)
        # shared by the groups of a run over several team sizes: one reward scale
        self.ret_stats = ret_stats if ret_stats is not None else RunningNorm(1).to(device)

    @torch.no_grad()
    def observe(self, reward: torch.Tensor, done: torch.Tensor) -> tuple[list[float], list[int]]:
        """``reward``, ``done``: (K, T). Returns the ended episodes' returns and lengths."""
        returns, lengths, discounted = [], [], []
        for t in range(reward.shape[1]):
            r, d = reward[:, t], done[:, t]
            self.ret += r
            self.len += 1
            self.discounted = self.discounted * self.gamma + r
            discounted.append(self.discounted)
            returns.append(self.ret)
            lengths.append(self.len)
            self.ret = torch.where(d, 0.0, self.ret)
            self.len = torch.where(d, 0.0, self.len)
            self.discounted = torch.where(d, 0.0, self.discounted)
        self.ret_stats.update(torch.stack(discounted, 1).reshape(-1, 1))
        # the ended episodes picked once per rollout: one transfer, no sync per step
        ended = torch.stack([torch.stack(returns, 1)[done], torch.stack(lengths, 1)[done]])
        ret, length = ended.tolist()
        return ret, [int(x) for x in length]

    def scale(self, reward: torch.Tensor) -> torch.Tensor:
        std = torch.sqrt(self.ret_stats.var + self.ret_stats.eps)
        return (reward / std).clamp(-CLIP_OBSERVATION, CLIP_OBSERVATION)


class StepCosts:
    """Each ``VectorEnv.step``'s constraint values (K, N, 8) and violation counts (K, N),
    on the host, in step order: the TorchRL env does not pass its infos on, so the trainer
    reads them where the step returns them."""

    def __init__(self, vector_env: Any) -> None:
        self.rows: list[tuple[np.ndarray, np.ndarray]] = []
        step = vector_env.step

        def recording(actions: Any) -> Any:
            out = step(actions)
            infos = out[4]
            self.rows.append((_host(infos["constraint_values"]), _host(infos["cost"])))
            return out

        vector_env.step = recording

    def take(self) -> list[tuple[np.ndarray, np.ndarray]]:
        rows, self.rows = self.rows, []
        return rows


def _host(x: Any) -> np.ndarray:
    return np.asarray(x.get() if hasattr(x, "get") and not isinstance(x, np.ndarray) else x)


class Trainer:
    """TorchRL's PPO under a ``baselines.runs.Run`` (``baselines.runs.Trainer``)."""

    def __init__(self, run: Run, algo: str, args: argparse.Namespace) -> None:
        check_options(run.settings, algo, args)
        self.run, self.args = run, args
        self.hp = {**HYPERPARAMETERS, **run.settings.hyperparameters}
        self.collectors: list[Any] = []
        self.costs: StepCosts | None = None
        self.lagrangian: Lagrangian | None = None
        self.robot_steps = 0
        self.totals = {"collect_s": 0.0, "update_s": 0.0, "episodes": 0}

    def build(self) -> dict[str, Any]:
        from torchrl.collectors import Collector
        from torchrl.data import LazyTensorStorage, ReplayBuffer
        from torchrl.data.replay_buffers.samplers import SamplerWithoutReplacement

        from uvms_env.vector.sb3 import PART_SEED_STRIDE

        s, a, hp = self.run.settings, self.args, self.hp
        device = parse_device(a.device, a.backend)
        pool = seeded_pool(s.scenario, s.overrides, s.geometry_pool)
        torch.set_num_threads(a.torch_threads)
        torch.manual_seed(s.seed + self.run.config["resumes"])
        envs = []  # one TorchRL env per group of env copies (``RunSettings.groups``)
        for j, group in enumerate(s.groups()):
            env = make_env(
                s.scenario, s.num_envs, a.backend, device, a.dtype, pool, a.env_threads, group
            )
            env.set_seed(self.run.env_seed + j * PART_SEED_STRIDE)
            envs.append(env)
        dev = self.dev = envs[0].device
        if s.cost is not None:
            self.costs = StepCosts(envs[0].vector_env)
            self.lagrangian = Lagrangian(s.cost, s.num_envs * envs[0].vector_env.n)
        actor, critic, actor_net, critic_net = build_modules(envs[0], hp)
        loss = ppo_loss(actor, critic, hp)
        optimizer = torch.optim.Adam(loss.parameters(), lr=hp["lr"])
        shared = RunningNorm(1).to(dev)
        trackers = [EpisodeTracker(s.num_envs, hp["gamma"], dev, shared) for _ in envs]
        if s.resume is not None:
            self.robot_steps = self._restore(
                Path(s.resume), actor_net, critic_net, optimizer, trackers[0]
            )
        steps = int(hp["rollout_steps"])
        rows_per_batch = s.num_envs * steps
        robots = sum(env.vector_env.n for env in envs)
        self.robot_steps_per_batch = rows_per_batch * robots
        remaining = max(0, s.robot_steps - self.robot_steps)
        self.iterations = math.ceil(remaining / self.robot_steps_per_batch)
        self.collectors = [
            Collector(
                env,
                actor,
                frames_per_batch=rows_per_batch,
                total_frames=max(1, self.iterations) * rows_per_batch,
                device=dev,
                auto_register_policy_transforms=False,  # the actor is memoryless: no InitTracker
            )
            for env in envs
        ]
        samples = rows_per_batch * robots  # robot samples per iteration, every group
        minibatch = max(1, samples // int(hp["minibatches"]))
        self.buffer = ReplayBuffer(
            storage=LazyTensorStorage(samples, device=dev),
            sampler=SamplerWithoutReplacement(),
            batch_size=minibatch,
        )
        self.loss, self.optimizer, self.trackers = loss, optimizer, trackers
        self.actor_net, self.critic_net = actor_net, critic_net
        self.run.config["hardware"].update(hardware(dev))
        return {
            "backend": a.backend,
            "device": str(dev),
            "dtype": a.dtype,
            "geometry_pool": pool,
            "env_threads": a.env_threads,
            "robots": s.num_envs * robots,
            "team_sizes": [env.vector_env.n for env in envs],
            "hyperparameters": hp,
            "minibatch_robot_samples": minibatch,
            "robot_steps_per_iteration": self.robot_steps_per_batch,
            "torch_threads": torch.get_num_threads(),
        }

    def learn(self) -> int:
        from tensordict import TensorDict

        from uvms_env.vector.torchrl_env import GROUP

        if self.iterations == 0:
            return self.robot_steps
        # the collectors reset their envs when they were made: stepping starts here
        self.run.begin(self.robot_steps_per_batch)
        hp, loss = self.hp, self.loss
        tick = time.perf_counter()
        for batches in zip(*self.collectors, strict=True):
            if self.dev.type == "cuda":
                torch.cuda.synchronize(self.dev)  # the timings below are the device's
            collect_s = time.perf_counter() - tick
            tock = time.perf_counter()
            returns: list[float] = []
            lengths: list[int] = []
            samples, observations = [], []
            for batch, tracker in zip(batches, self.trackers, strict=True):
                reward = batch["next", GROUP, "reward"]  # (K, T, N, 1): the team's, per robot
                done = batch["next", "done"][..., 0]
                if self.lagrangian is not None:
                    reward = reward - self._penalties(done)
                    batch["next", GROUP, "reward"] = reward
                # the team's return as robot 0 receives it (the SB3 trainer's monitor, too)
                ended_returns, ended_lengths = tracker.observe(reward[:, :, 0, 0], done)
                returns += ended_returns
                lengths += ended_lengths
                if hp["scale_reward"]:
                    batch["next", GROUP, "reward"] = tracker.scale(reward)
                with torch.no_grad():
                    loss.value_estimator(
                        batch,
                        params=loss.critic_network_params,
                        target_params=loss.target_critic_network_params,
                    )
                # robot samples (K T N): one policy for every robot, teams of any size
                robots = batch.get(GROUP).exclude("next").reshape(-1)
                samples.append(TensorDict({GROUP: robots}, batch_size=robots.batch_size))
                observations.append(robots["observation"])
            self.buffer.extend(torch.cat(samples) if len(samples) > 1 else samples[0])
            for _ in range(int(hp["epochs"]) * int(hp["minibatches"])):
                values = loss(self.buffer.sample())
                total = values["loss_objective"] + values["loss_critic"]
                if "loss_entropy" in values.keys():
                    total = total + values["loss_entropy"]
                total.backward()
                nn.utils.clip_grad_norm_(loss.parameters(), hp["max_grad_norm"])
                self.optimizer.step()
                self.optimizer.zero_grad()
            if hp["normalize_observation"]:
                # after the update: the rollout was collected and is learned from with
                # the same statistics, so the PPO ratio starts at 1
                obs = torch.cat(observations)
                self.actor_net.norm.update(obs)
                self.critic_net.norm.update(obs)
            for collector in self.collectors:
                collector.update_policy_weights_()
            if self.dev.type == "cuda":
                torch.cuda.synchronize(self.dev)
            self.totals["collect_s"] += collect_s
            self.totals["update_s"] += time.perf_counter() - tock
            self.totals["episodes"] += len(returns)
            self.robot_steps += self.robot_steps_per_batch
            cost = multiplier = None
            if self.lagrangian is not None:
                cost = self.lagrangian.end_rollout()
                multiplier = self.lagrangian.multiplier
            self.run.after_iteration(
                self,
                self.robot_steps,
                returns=returns,
                lengths=lengths,
                episode_cost=cost,
                multiplier=multiplier,
            )
            tick = time.perf_counter()
        return self.robot_steps

    def _penalties(self, done: torch.Tensor) -> torch.Tensor:
        """(K, T, N, 1) multiplier times each robot's constraint cost of the rollout's T
        steps (``baselines.lagrangian``), with the multiplier the rollout ran with."""
        assert self.costs is not None and self.lagrangian is not None
        rows = self.costs.take()
        k, steps = done.shape
        if len(rows) != steps:
            raise RuntimeError(f"recorded {len(rows)} env steps for a rollout of {steps}")
        ended = done.cpu().numpy()
        n = rows[0][1].shape[1]
        multiplier = self.lagrangian.multiplier
        cost = np.stack(
            [
                self.lagrangian.penalize(g, count, np.repeat(ended[:, t], n))
                for t, (g, count) in enumerate(rows)
            ],
            1,
        )  # (K N, T) -> (K, T, N, 1) below
        cost = cost.reshape(k, n, steps).transpose(0, 2, 1)[..., None]
        return torch.as_tensor(multiplier * cost, dtype=torch.float32, device=self.dev)

    def save(self, folder: Path, resumable: bool = False) -> None:
        """The actor; in the run folder (or ``resumable``) also what a resume reads."""
        folder.mkdir(parents=True, exist_ok=True)
        save_actor(self.actor_net, self._actor_settings(), folder / ACTOR_FILE)
        if resumable or folder == self.run.folder:
            torch.save(self._trainer_state(), folder / TRAINER_FILE)

    def checkpoint(self, robot_steps: int) -> None:
        self.save(self.run.folder / "checkpoints" / f"robot_steps_{robot_steps}", True)

    def results(self) -> dict[str, Any]:
        return {k: round(v, 1) if isinstance(v, float) else v for k, v in self.totals.items()}

    def close(self) -> None:
        for collector in self.collectors:
            collector.shutdown()
        self.collectors = []

    def _actor_settings(self) -> dict[str, Any]:
        return {
            "observation_size": self.actor_net.body[0].in_features,
            "action_size": self.actor_net.body[-1].out_features,
            "hidden": list(self.hp["hidden"]),
            "normalize_observation": bool(self.hp["normalize_observation"]),
        }

    def _trainer_state(self) -> dict[str, Any]:
        def host(state: dict[str, Any]) -> dict[str, Any]:
            return {k: v.detach().cpu() for k, v in state.items()}

        return {
            "robot_steps": self.robot_steps,
            "actor": host(self.actor_net.state_dict()),
            "critic": host(self.critic_net.state_dict()),
            "return_stats": host(self.trackers[0].ret_stats.state_dict()),
            "optimizer": self.optimizer.state_dict(),
        }

    def _restore(
        self,
        path: Path,
        actor: nn.Module,
        critic: nn.Module,
        optimizer: Any,
        tracker: EpisodeTracker,
    ) -> int:
        """Load ``trainer.pt`` of a run folder or checkpoint; returns its robot-steps."""
        file = path / TRAINER_FILE if path.is_dir() else path
        if not file.is_file():
            raise FileNotFoundError(f"nothing to resume at {path} (expected {TRAINER_FILE})")
        state = torch.load(file, map_location=self.dev, weights_only=True)
        actor.load_state_dict(state["actor"])
        critic.load_state_dict(state["critic"])
        tracker.ret_stats.load_state_dict(state["return_stats"])
        optimizer.load_state_dict(state["optimizer"])
        print(f"resuming {file} at {state['robot_steps']} robot-steps")
        return int(state["robot_steps"])


def hardware(device: torch.device) -> dict[str, Any]:
    """The libraries and the GPU, added to the run's hardware record."""
    import torchrl

    info: dict[str, Any] = {"torch": torch.__version__, "torchrl": torchrl.__version__}
    if device.type == "cuda":
        info["gpu"] = torch.cuda.get_device_name(device)
    return info
