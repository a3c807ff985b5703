"""``python -m baselines`` lists the command lines of this package."""

print("python -m baselines.train --library {sb3,benchmarl,rllib} --help  train a shared policy")
print("python -m baselines.imitate --help                               collect, bc, dagger")
print("python -m baselines.evaluate --help   compare policies on the same seeded episodes")
print("python -m baselines.rl.plot --help    learning curves of training runs")
