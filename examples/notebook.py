"""A notebook-style walk through the Python API (run: .venv/bin/python examples/notebook.py).

Runs BIRL-G on a random scene for three seeds, reads the per-iteration policy loss, the
learned weights and the learned paths back as pandas tables and numpy arrays, saves a figure
of each run (scene, demonstrations, learned paths) and learns once more in memory from the
first run's scene and demonstrations with MaxEnt.
"""

from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # a script saves figures; in a notebook, leave the inline backend
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from pipeline import api  # noqa: E402

out = Path("outputs/example")
rows = []
for seed in (0, 1, 2):
    run = api.run(["scene=random", f"seed={seed}", "graph=small"], run_dir=out / f"seed{seed}")
    curve = run.messages("evaluate", "/eval/policy_loss")  # weights: numpy arrays per row
    paths = run.paths()  # start index -> (K, 2) learned path on the adaptive graph
    ax = run.plot()
    ax.figure.savefig(out / f"seed{seed}.png", dpi=120)
    plt.close(ax.figure)
    rows.append({"seed": seed, "iterations": len(curve) - 1,
                 "first_loss": curve["ref"].iloc[0], "final_loss": curve["ref"].iloc[-1],
                 "policy_loss_norm": run.metrics["policy_loss_norm"],
                 "path_length": sum(float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum())
                                    for p in paths.values()),
                 "final_weights": np.round(curve["weights"].iloc[-1], 3).tolist()})

print(pd.DataFrame(rows).to_markdown(index=False))
print(f"figures: {', '.join(str(out / f'seed{s}.png') for s in (0, 1, 2))}")

# An earlier run, opened again; its scene and demonstrations learned from in memory.
first = api.open_run(out / "seed0")
demos = first.messages("demos", "/demos").to_dict("records")
learned = api.learn(first.scene(), demos, method="maxent", overrides=["graph=small"])
print("MaxEnt in memory:", dict(zip(learned.feature_names, np.round(learned.weights, 3).tolist(),
                                    strict=True)))
