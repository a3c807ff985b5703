"""Entry point: ``python -m baselines.train`` (see ``baselines.rl.train``)."""

from baselines.rl.train import main

if __name__ == "__main__":
    main()
