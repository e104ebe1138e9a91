"""The metrics.json keys (written by the evaluate stage), as patterns with what each holds: a
sweep's `objective` must name one, a sweep's table (pipeline.app.summary) tells metrics from
settings by them, and the docs' metrics page is generated from them (pipeline.tools.docs).
Apart from pipeline.app.config so the table needs none of the run's imports."""

from __future__ import annotations

import re

from pipeline.core.social import INTIMATE_ZONE, PATH_METRICS, PERSONAL_ZONE

# What each social metric of a path measures; PATH_METRICS says how the paths from all
# starts combine into the run's value.
PATH_METRIC_MEANING: dict[str, str] = {
    "relation_crossings": "crossings of the path with social links (the segment between two "
                          "related persons): passes from one side to the other through one, "
                          "also at a vertex on it; a touch and turn back is none",
    "intimate_intrusion_m": f"metres of path inside a person's intimate zone ({INTIMATE_ZONE} m)",
    "personal_intrusion_m": f"metres of path inside a person's personal zone ({PERSONAL_ZONE} m)",
    "min_distance_to_person": "smallest distance from the path to a person's centre, m",
    "path_length": "length of the path, m",
    "time_to_goal": "duration of the path, s",
    "success": "1 when the path reaches the goal, else 0",
    "obstacle_collisions": "1 when the path comes closer than `robot_radius` to an "
                           "obstacle, else 0 (scenes with obstacles only)",
    "min_distance_to_obstacle": "smallest clearance along the path, m (scenes with "
                                "obstacles only)",
}

# Tests check real runs' metrics.json against them (test_transfer, test_learning), so
# the two stay in step.
_PATH = "(" + "|".join(PATH_METRICS) + ")"
METRIC_KEYS: dict[str, str] = {
    rf"(ref_)?{_PATH}": "a social metric of the learned paths (below) on the adaptive graph; "
                        "`ref_`: on the reference roadmap",
    rf"transfer_.+_(policy_loss(_norm)?|{_PATH})": "`evaluate.transfer_scenes`: the learned "
        "weights planned with on another scene's roadmap (its name in the key)",
    r"policy_loss(_ref)?(_initial|_iter_\d+)?": "policy loss on the adaptive graph (`_ref`: "
        "on the reference roadmap) of the final weights, the initial ones, or iteration NN's; "
        "synthetic experts only",
    r"policy_loss_ref_(polite|rude)": "the roadmap policy loss of the contrasting behaviour "
                                      "(rude; polite when the true reward is rude)",
    r"policy_loss_norm": "the roadmap policy loss divided by the contrasting behaviour's: "
                         "0 is the expert, 1 as bad as the contrast",
    r"weight_((std|rhat|ess)_)?\w+": "the learned weight of a feature; sampling methods also "
                                     "its posterior std, split R-hat and bulk ESS",
    r"mcmc_(acceptance_rate|ess_min|rhat_max|chains)": "sampling methods: acceptance rate, "
                                                       "smallest ESS and largest R-hat over the "
                                                       "weights, number of chains",
    r"frechet_to_demos(_max)?": "demonstrations without a true reward: mean (max) Fréchet "
                                "distance of the learned paths to them (both resampled every "
                                "0.1 m, however densely either is sampled), m",
    r"demos_(count|unreached)": "demonstrations without a true reward: how many were learned "
                                "from, and how many of them do not reach the goal",
    r"demos_min_distance_to_person": "demonstrations without a true reward: the smallest "
                                     "distance from any of them (held out or not) to a "
                                     "person's centre, m",
    r"time_\w+_s": "wall-clock seconds of a stage (or a part of one); never in an artefact",
    r"graph_demo_node_share": "share of the adaptive graph's nodes that are demonstration "
                              "waypoints",
    r"heldout_(count|(frechet_m|min_distance_error_m)(_shortest)?)": "`evaluate.holdout`: "
        "the held-out demonstrations, their median Fréchet distance to the learned paths and "
        "median error of the smallest distance to a person (`_shortest`: of the fastest path)",
    r"heldout_(frechet_m|min_distance_error_m)(_shortest)?_taut": "`evaluate.holdout`, "
        "undiscounted MDPs: the same medians for the learned (`_shortest`: fastest) roadmap "
        "paths pulled taut under their own reward (straight on wherever a straight segment is "
        "feasible and costs no more): what a planner not held to the lattice would drive; "
        "where the comparison with the shortest path differs from the lattice paths', the "
        "summary warns that the lattice decided it",
    r"ref_min_distance_to_person_taut": "undiscounted MDPs: the smallest distance to a "
        "person's centre of the learned roadmap paths pulled taut under the learned reward "
        "(as `heldout_*_taut`), m; the summary warns when it is over 5 cm below "
        "`ref_min_distance_to_person`",
    r"heldout_frechet_m(_shortest)?_max": "`evaluate.holdout`: the largest Fréchet distance of "
        "a held-out demonstration to its learned path (`_shortest`: to the fastest path); a "
        "start whose paths go the other way round shows here, not in the median",
    r"heldout_log_likelihood(_shortest)?": "`evaluate.holdout`: mean log likelihood per "
        "held-out demonstration under the default learner's Boltzmann model (Boltzmann "
        "policy over the lattice of alternatives, relative to its base measure), β fitted to the "
        "training demonstrations (`_shortest`: of the cost per second alone); higher predicts "
        "better",
}


def is_metric_key(key: str) -> bool:
    return any(re.fullmatch(pattern, key) for pattern in METRIC_KEYS)
