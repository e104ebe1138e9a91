"""Benchmark: real buildings with the defaults (`make bench`). Writes
results/bench/buildings.csv, one row per run: the shipped maps (metropolis, the office, the
30 × 50 m warehouse) learned from the optimal expert; random scenes on the office and
warehouse maps (persons, starts and goal drawn with the seed: scenes nobody tuned for)
learned the same way; and a reward learned on metropolis deployed on each shipped map
without any demonstration there (`expert=none birl=fixed`). Columns: graph nodes, seconds
per stage and end to end, success, collisions, roadmap crossings, policy loss where the
true reward is known: on the roadmap, and normalised by the rude policy's there (which is
small, and the ratio unsteady, where few persons are near any route).

    python -m pipeline.tools.bench_buildings                  # seeds 0-4 (~2 min on 2 cores)
    python -m pipeline.tools.bench_buildings --seeds 0 --scenes warehouse
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import pandas as pd

from pipeline.artefacts import codec, read_artefact
from pipeline.artefacts.topics import ARTEFACT_FILE, STAGES
from pipeline.tools import output_directory, run_tool
from pipeline.tools.bench import RESULTS, run_in_process, seed_number

SCENES = ("metropolis", "office", "warehouse")
# random scenes on these maps: scene name -> the map
RANDOM_ON_MAPS = {"random on office map": "data/maps/office.yaml",
                  "random on warehouse map": "data/maps/warehouse.yaml"}
KEYS = ("success", "obstacle_collisions", "relation_crossings", "ref_relation_crossings",
        "ref_intimate_intrusion_m", "policy_loss_ref", "policy_loss_ref_rude",
        "policy_loss_norm")


def scene_overrides(scene: str) -> list[str]:
    if scene in RANDOM_ON_MAPS:
        return ["scene=random", f"scene.map={RANDOM_ON_MAPS[scene]}"]
    return [f"scene={scene}"]


def one_run(run_dir: Path, case: str, scene: str, seed: int, *overrides: str) -> dict:
    t0 = time.perf_counter()
    m = run_in_process(run_dir, *scene_overrides(scene), f"seed={seed}", *overrides)
    row: dict = {"case": case, "scene": scene, "seed": seed,
                 "wall_s": round(time.perf_counter() - t0, 2),
                 "graph_nodes": len(codec.decode_nodes(
                     read_artefact(run_dir / ARTEFACT_FILE["graph"])))}
    row.update({f"{s}_s": m.get(f"time_{s}_s") for s in STAGES})
    row.update({k: m.get(k) for k in KEYS})
    return row


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", nargs="+", default=list(SCENES), choices=SCENES)
    parser.add_argument("--random-on-maps", dest="random_on_maps", nargs="*",
                        default=list(RANDOM_ON_MAPS), choices=list(RANDOM_ON_MAPS))
    parser.add_argument("--seeds", nargs="+", type=seed_number, default=list(range(5)))
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    output_directory(parser, args.out)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for seed in args.seeds:
            learned = Path(tmp) / f"metropolis-{seed}"
            for scene in args.scenes:
                run = learned if scene == "metropolis" else Path(tmp) / f"{scene}-{seed}"
                rows.append(one_run(run, "optimal expert", scene, seed))
                print(rows[-1], flush=True)
            for k, scene in enumerate(args.random_on_maps):
                rows.append(one_run(Path(tmp) / f"random-{k}-{seed}", "optimal expert", scene,
                                    seed))
                print(rows[-1], flush=True)
            if "metropolis" not in args.scenes:  # the reward to deploy
                run_in_process(learned, "scene=metropolis", f"seed={seed}")
            for scene in args.scenes:
                rows.append(one_run(Path(tmp) / f"deploy-{scene}-{seed}",
                                    "deployed from metropolis, no demonstrations", scene, seed,
                                    "expert=none", "birl=fixed", f"birl.from_run={learned}"))
                print(rows[-1], flush=True)
    table = pd.DataFrame(rows)
    path = args.out / "buildings.csv"
    table.to_csv(path, index=False)
    print(table.groupby(["case", "scene"])[["wall_s", "graph_nodes", *KEYS]].agg(["median", "max"])
          .to_string())
    print(f"wrote {path}")


if __name__ == "__main__":
    run_tool(main)
