"""Command line of the geometry bank (``uvms_env.scenarios.bank``), outside the package's imports
so that ``python -m`` runs it cleanly:

    python -m uvms_env.vector.build_bank random --n-agents 4 --seeds 0:1024

May import: ``uvms_env.scenarios.bank``.
"""

from uvms_env.scenarios.bank import main

if __name__ == "__main__":
    main()
