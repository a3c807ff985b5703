"""Entry point: ``python -m baselines.train [--engine {sb3,rllib,torchrl}] ...``.

``sb3`` (default): stable-baselines3 on one machine (``baselines.rl.train``); ``rllib``:
Ray RLlib, local or on a cluster (``baselines.distributed.rllib_train``); ``torchrl``:
TorchRL's PPO with the environment, rollouts and updates on one device, a GPU with
``--backend cuda`` (``baselines.rl.torchrl_ppo``). Every other argument goes to the
chosen engine.
"""

import argparse
import sys

ENGINES = ("sb3", "rllib", "torchrl")


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(add_help=False)
    ap.add_argument("--engine", choices=ENGINES, default="sb3")
    args, rest = ap.parse_known_args(sys.argv[1:] if argv is None else argv)
    if args.engine == "rllib":
        from baselines.distributed.rllib_train import main as engine_main
    elif args.engine == "torchrl":
        from baselines.rl.torchrl_ppo import main as engine_main
    else:
        from baselines.rl.train import main as engine_main
    engine_main(rest)


if __name__ == "__main__":
    main()
