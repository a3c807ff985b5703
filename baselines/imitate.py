"""Entry point: ``python -m baselines.imitate`` (see ``baselines.imitation.cli``)."""

from baselines.imitation.cli import main

if __name__ == "__main__":
    main()
