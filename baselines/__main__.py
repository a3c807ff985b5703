"""``python -m baselines`` lists the command lines of this package."""

print("python -m baselines.evaluate --help   compare policies on the same seeded episodes")
