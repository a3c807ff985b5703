"""The environments: PettingZoo ``ParallelEnv`` (decentralized), Gymnasium view (centralized).

    import uvms_env
    env = uvms_env.parallel_env(scenario="paper")        # or pettingzoo.make("parallel",
    obs, infos = env.reset(seed=0)                         #   "uvms_env/CoopTransport-v1")
    obs, rewards, terminated, truncated, infos = env.step(
        {agent: env.action_space(agent).sample() for agent in env.agents}
    )

The adapters and the episode's flow, one job per module, each said in its docstring
(the PettingZoo environment: ``parallel``; the Gymnasium view: ``gym_wrapper``; the
keywords: ``options``; the episode's flow: ``core`` on the one-environment
``scalar_engine``; pictures: ``render``). The task's rules are in ``uvms_env.task``, the
robot's own side in ``uvms_env.robot``, the physics in ``uvms_env.sim``; their public
names are re-exported here as before. Reference: docs/environment.md.

May import everything in ``uvms_env`` below it (models, dynamics, sim, navigation,
scenarios, task, robot), plus pettingzoo, gymnasium and (lazily) matplotlib.
"""

from uvms_env.env.gym_wrapper import CoopTransportGymEnv
from uvms_env.env.parallel import CoopTransportEnv, parallel_env
from uvms_env.env.registration import ENV_ID
from uvms_env.env.render import save_video
from uvms_env.robot.observation import (
    OBSERVATION_FIELDS,
    OBSERVATION_SIZE,
    OBSERVATION_STRUCTURE,
    make_navigator,
)
from uvms_env.task.constraints import CONSTRAINTS, MANIPULABILITY_EPS
from uvms_env.task.metrics import METRICS, goal_errors
from uvms_env.task.reward import REWARD_TERMS, RewardWeights
from uvms_env.task.rules import Task, TaskArrays

__all__ = [
    "CONSTRAINTS",
    "ENV_ID",
    "MANIPULABILITY_EPS",
    "METRICS",
    "OBSERVATION_FIELDS",
    "OBSERVATION_SIZE",
    "OBSERVATION_STRUCTURE",
    "REWARD_TERMS",
    "CoopTransportEnv",
    "CoopTransportGymEnv",
    "RewardWeights",
    "Task",
    "TaskArrays",
    "goal_errors",
    "make_navigator",
    "parallel_env",
    "save_video",
]
