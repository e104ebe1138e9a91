"""A notebook-style walk through the Python API (run: .venv/bin/python examples/notebook.py).

Runs BIRL-G on a random scene for three seeds, then reads the per-iteration policy loss and
the learned weights back as pandas tables.
"""

import pandas as pd

from pipeline import api

rows = []
for seed in (0, 1, 2):
    run_dir = f"outputs/example/seed{seed}"
    metrics = api.run(["scene=random", f"seed={seed}", "graph=small"], run_dir=run_dir)
    curve = api.messages(run_dir, "evaluate", "/eval/policy_loss")
    rows.append({"seed": seed, "iterations": len(curve),
                 "first_loss": curve["ref"].iloc[0], "final_loss": curve["ref"].iloc[-1],
                 "policy_loss_norm": metrics["policy_loss_norm"]})

print(pd.DataFrame(rows).to_markdown(index=False, floatfmt=("g", "g", ".4f", ".4f", ".4f")))
