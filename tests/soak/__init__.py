"""The soak run (`make soak` / `python -m tests.soak`): 20 simulated machines, random faults, loss and growth.

Not collected by pytest (no test_ files); see docs/reliability.md.
"""
