"""The one screen a run ends with (`summary_text`), from its metrics: the headline numbers,
and each warning exactly when its rule holds (each rule's docstring says it and the case
that made it). Text from numbers only: the evaluate stage prints it, the docs generator
prints the same for the README's sample output."""

from __future__ import annotations

import numpy as np

from pipeline.artefacts import export_topics
from pipeline.artefacts.topics import STAGES
from pipeline.irl.diagnostics import AGREED_ESS, AGREED_RHAT, MIN_DRAWS, chains_agree
from pipeline.irl.prior import Prior


def worse_than_initial(m: dict) -> list[str]:
    """A warning line when the learned weights lose more than the initial ones, on the graph
    or the roadmap, saying what that means."""
    worse = [f"{name} {m[final]:.4f} > {m[initial]:.4f}" for name, final, initial in (
        ("roadmap", "policy_loss_ref", "policy_loss_ref_initial"),
        ("graph", "policy_loss", "policy_loss_initial")) if m[final] > m[initial] + 1e-9]
    if not worse:
        return []
    return [f"  warning          the learned weights lose more than the initial ones "
            f"({', '.join(worse)}): the demonstrations are explained best by weights that "
            "are further from the true reward than the start was (few or noisy "
            "demonstrations, or features the expert does not share); look at more seeds or "
            "demonstrations before reading this run's weights"]


# How much closer to a person than every demonstration (closer_than_demos), or than the
# roadmap's paths (graph_less_polite), learned paths may pass before the summary warns: a
# path on a graph follows a distance only to about its resolution (a walker passed people at
# 0.39 m on a random scene, the reward learned from its paths at 0.38 m)
CLOSER_MARGIN_M = 0.05
# Held-out medians (Fréchet distance, min-distance error) of the learned and the shortest
# paths this close are a tie: roadmap paths follow a route only to about its resolution (a
# hall's learned paths, 7 mm farther than the shortest in 2.49 m, were called "worse than no
# reward" beside a better held-out likelihood)
HELDOUT_TIE_M = 0.05


def heldout_verdict(learned: float, shortest: float) -> int:
    """How a held-out median of the learned paths compares with the shortest paths': -1
    better, 1 worse, each by more than HELDOUT_TIE_M, 0 a tie. One comparison for every
    rule, with a rounding's slack: a difference of 0.05 m (0.14 m against 0.09 m) is a tie,
    not a difference "as far" and "worse" both left unsaid."""
    lag = learned - shortest
    return 0 if abs(lag) <= HELDOUT_TIE_M + 1e-9 else (1 if lag > 0 else -1)


# A learner's hinge this close to the demonstrators' closest approach already says it
NEAR_HINGE_M = 0.25
# How much further into personal zones than the roadmap's paths the graph's may go before
# the summary warns (graph_less_polite): more than this, and half as far again. Resolution
# alone moves it by tenths of a metre (metropolis' default run: 9.19 m against 9.89 m); a
# deployment's graph paths went 3.22 m in against the roadmap's 0.90 m, predicting the
# walkers 4.41 m away (median Fréchet) against the roadmap's 1.18 m, unsaid
PERSONAL_MARGIN_M = 1.0
PERSONAL_RATIO = 1.5


def graph_less_polite(m: dict, roadmap_ruder_than_demos: bool = False) -> list[str]:
    """A warning line when the graph's paths cross more social links, intrude further into
    intimate zones, pass a person closer (by over CLOSER_MARGIN_M) or go much further into
    personal zones (PERSONAL_MARGIN_M, PERSONAL_RATIO) than the same reward's roadmap
    paths: the graph's detours, if it has
    any, are worse under the reward than the roadmap's (a graph grown without
    demonstrations and without its medial-axis nodes, metropolis, 460 nodes: 0-18
    crossings over eight seeds, the roadmap's 0), and these are the paths a robot would be
    given. Not where a true reward says the graph's paths lose no more than the roadmap's
    (`reward=rude`, which no link or person costs: 15 crossings against 0, policy loss 0
    against 0.06, and the advice to deploy the roadmap's paths was wrong). With
    `roadmap_ruder_than_demos` (`closer_than_demos`' line follows) the roadmap's paths are
    not offered as the ones to deploy: a deployment on a walker's scene was told to deploy
    them, and on the next line that they are ruder than every demonstrator."""
    if m.get("policy_loss", np.inf) <= m.get("policy_loss_ref", -np.inf):
        return []
    worse = [f"{what} {m[key]:{spec}}{unit} against {m['ref_' + key]:{spec}}{unit}"
             for what, key, spec, unit in (("crossings", "relation_crossings", ".0f", ""),
                                           ("intimate", "intimate_intrusion_m", ".2f", " m"))
             if key in m and "ref_" + key in m and m[key] > m["ref_" + key] + 1e-9]
    # and closer to a person, by more than a roadmap path follows a distance (a deployment's
    # graph paths passed 0.28 m from a person's centre, its roadmap's 0.34 m, unsaid), than
    # the roadmap's paths on the lattice or pulled taut, whichever passes closer (a room's
    # graph paths at 0.83 m were "ruder" than the roadmap's 1.20 m, 0.87 m pulled taut)
    closest = m.get("min_distance_to_person"), min(
        m.get("ref_min_distance_to_person", np.inf), m.get("ref_min_distance_to_person_taut",
                                                           np.inf))
    if closest[0] is not None and np.isfinite(closest[1]) and \
            closest[0] < closest[1] - CLOSER_MARGIN_M:
        worse.append(f"min distance {closest[0]:.2f} m against {closest[1]:.2f} m")
    personal, ref_personal = m.get("personal_intrusion_m"), m.get("ref_personal_intrusion_m")
    if personal is not None and ref_personal is not None and \
            personal > max(ref_personal + PERSONAL_MARGIN_M, PERSONAL_RATIO * ref_personal):
        worse.append(f"personal {personal:.2f} m against {ref_personal:.2f} m")
    if not worse:
        return []
    roadmap = f"the roadmap's paths (birlg-export: {export_topics.LEARNED_REF})"
    advice = (f"it lacks detours as good as the roadmap's (grow it further: graph.max_nodes); "
              f"{roadmap} are the better ones, but see the next line"
              if roadmap_ruder_than_demos else
              f"it lacks detours as good as the roadmap's; deploy {roadmap} or grow it further "
              "(graph.max_nodes)")
    return ["  warning          the graph's paths are ruder than the roadmap's under the same "
            f"reward ({', '.join(worse)}): {advice}"]


def heldout_no_better(m: dict) -> list[str]:
    """A warning line when the learned paths predict the held-out demonstrations as well as
    the shortest paths (median Fréchet distance and min-distance error each within
    HELDOUT_TIE_M, as where the learned reward plans the shortest paths from the held-out
    starts): a Nav2-like planner that keeps off walls, learned without a wall feature, was
    told nothing, and its held-out log likelihood above the shortest path's suggested the
    opposite."""
    given = [(m.get(k), m.get(k + "_shortest"))
             for k in ("heldout_frechet_m", "heldout_min_distance_error_m")]
    pairs = [(a, b) for a, b in given if a is not None and b is not None]
    if not pairs or any(heldout_verdict(a, b) for a, b in pairs):
        return []
    return ["  warning          the learned paths are as far from the held-out demonstrations "
            f"as the shortest paths are (within {HELDOUT_TIE_M:.2f} m): on these scenes the "
            "learned reward predicts them no better than no reward does (the demonstrators "
            "may keep to something the learner's features cannot say: see the features docs "
            "and birl.features)"]


def heldout_worse(m: dict) -> list[str]:
    """A warning line for each held-out median (Fréchet distance, min-distance error) by
    which the learned paths predict the held-out demonstrations worse than the shortest
    paths, by more than HELDOUT_TIE_M."""
    def worse(key: str) -> bool:
        learned, shortest = m.get(key), m.get(key + "_shortest")
        return learned is not None and shortest is not None and \
            heldout_verdict(learned, shortest) > 0
    lines = []
    if worse("heldout_frechet_m"):
        lines.append("  warning          the learned paths are farther from the held-out "
                     "demonstrations than the shortest paths are: on these scenes the "
                     "learned reward predicts them worse than no reward does")
    if worse("heldout_min_distance_error_m"):
        lines.append("  warning          the learned paths' closest approach to a person "
                     "differs more from the held-out demonstrations' than the shortest "
                     "paths' does (min-distance error): on these scenes the learned reward "
                     "predicts how closely they pass people worse than no reward does")
    return lines


def heldout_by_lattice(m: dict) -> list[str]:
    """A warning line when the comparison of the learned paths with the shortest paths on
    the held-out demonstrations (Fréchet distance, min-distance error) turns once both are
    pulled taut under their own reward (heldout_*_taut): a lead that goes (a lobby's learned
    paths kept 1.0 m from people by the lattice's staircases, 0.29 m pulled taut, and
    predicted the walkers as well as the shortest path: 1.07 m against 1.07 m), or a lag
    that goes (a room where the "worse than no reward" warning on the min-distance error,
    0.71 m against 0.56 m, was 0.03 m against 0.03 m pulled taut): the roadmap lattice made
    the difference, not the learned reward. A lead or a lag on the lattice is one beyond
    HELDOUT_TIE_M (`heldout_verdict`): a hall's 7 mm lag, a tie, was said to be the
    lattice's doing on the line after the one that called it none."""
    turned: dict[str, list[str]] = {"no better": [], "no worse": []}
    for what, key in (("Fréchet", "heldout_frechet_m"),
                      ("min-distance error", "heldout_min_distance_error_m")):
        if key + "_taut" not in m or key + "_shortest_taut" not in m:
            continue
        # on the lattice a lead or a lag beyond the tie: one within it was said to be none
        # (`heldout_no_better`), and no difference above can be the lattice's doing
        raw = heldout_verdict(m[key], m[key + "_shortest"])
        taut = m[key + "_taut"] - m[key + "_shortest_taut"]
        pair = f"{what} {m[key + '_taut']:.2f} m against {m[key + '_shortest_taut']:.2f} m"
        if raw < 0 <= taut:
            turned["no better"].append(pair)
        elif raw > 0 >= taut:
            turned["no worse"].append(pair)
    said = [f"{verdict} ({', '.join(pairs)})" for verdict, pairs in turned.items() if pairs]
    if not said:
        return []
    return ["  warning          pulled taut under their own reward, as a planner that is not "
            "held to the roadmap's lattice would drive them, the learned paths predict the "
            f"held-out demonstrations {' and '.join(said)} than the shortest paths: the "
            "difference above is the lattice's doing, not the learned reward's"]


def kept_by_lattice(m: dict, learned_from: float | None = None) -> list[str]:
    """A warning line when the learned roadmap paths, pulled taut under the learned reward
    (ref_min_distance_to_person_taut), pass a person closer, by over CLOSER_MARGIN_M, than
    on the lattice: their distance from people came from the lattice's staircases, not from
    the reward, and a planner not held to the lattice (Nav2 on the exported costmap) would
    pass closer (a lobby's learned paths: 1.0 m on the lattice, 0.29 m pulled taut). Where
    that is closer than every demonstration (`closer_than_demos`, which looks at the
    lattice paths, said nothing: the lobby's walkers kept 0.77 m), it says so, with the
    same advice."""
    raw, taut = m.get("ref_min_distance_to_person"), m.get("ref_min_distance_to_person_taut")
    if raw is None or taut is None or taut >= raw - CLOSER_MARGIN_M:
        return []
    demos = m.get("demos_min_distance_to_person", learned_from)
    ruder = "" if demos is None or not taut < demos - CLOSER_MARGIN_M <= raw else \
        f", closer than any demonstration ({demos:.2f} m){relearn_hint(m, demos)}"
    return [f"  warning          pulled taut under the learned reward, as a planner that is "
            f"not held to the roadmap's lattice would drive them, the roadmap paths pass "
            f"{taut:.2f} m from a person, not {raw:.2f} m: their distance from people is the "
            f"lattice's doing, not the learned reward's{ruder}"]


def relearn_hint(m: dict, demos: float) -> str:
    """"; learn again with ..." for a learned reward ruder than demonstrators who kept
    `demos` m from people, naming the features the learner lacks ('' if it has them)."""
    # Two ways to say it, neither always the better, sometimes only both: the squared hinge
    # (an unseen walker's 0.25 m paths went to 0.50 m) and a hinge where the demonstrators
    # keep (another's 0.40 m to 0.64 m with social@0.7). The hinge only to a learner without
    # one near that radius: one at 0.7 m already says what one at 0.52 m would.
    hinge = f"social@{max(demos, 0.1):.1f}"
    radii = [float(k.removeprefix("weight_social@")) for k in m if k.startswith("weight_social@")]
    ways = [f for f, has in (("social_squared", "weight_social_squared" in m),
                             (hinge, any(abs(r - demos) <= NEAR_HINGE_M for r in radii)))
            if not has]
    named = " or ".join(ways) if len(ways) < 2 else f"{ways[0]}, {ways[1]} or both"
    return f"; learn again with {named} added to birl.features (see the methods docs)" \
        if ways else ""


def closer_than_demos(m: dict, learned_from: float | None = None) -> list[str]:
    """A warning line when the learned roadmap paths pass a person closer than every
    demonstration did: a reward learned from people that is ruder than all of them (the
    planner's paths in the office, 0.62 m, taught paths of 0.39 m), which the held-out
    numbers need not show (no held-out demonstration, or none from the start that passes
    closest). A deployment without demonstrations of its own compares with `learned_from`,
    the demonstrations' closest approach in the run its weights were learned in (a lobby's
    reward, deployed on another layout, passed 0.67 m from a person, its walkers 0.74 m
    and more, unsaid)."""
    own = m.get("demos_min_distance_to_person")
    demos, learned = own if own is not None else learned_from, \
        m.get("ref_min_distance_to_person")
    if demos is None or learned is None or learned >= demos - CLOSER_MARGIN_M:
        return []
    hint = relearn_hint(m, demos)
    if own is None:
        return [f"  warning          the roadmap paths pass {learned:.2f} m from a person; the "
                f"demonstrations the weights were learned from kept {demos:.2f} m or more: on "
                f"this scene the reward is ruder than its demonstrators were{hint}"]
    return [f"  warning          the learned roadmap paths pass {learned:.2f} m from a person, "
            f"closer than any demonstration ({demos:.2f} m): the learned reward is ruder than "
            f"every demonstrator{hint}"]


def weights_at_box(m: dict, learner_features: list[str], box: Prior,
                   label: str = "weight box     ") -> list[str]:
    """A line naming the learned weights at a bound of the weight box (the demonstrations
    would have them further out: their size is the box's, not learned) or at its middle
    (where the default learner leaves what the demonstrations say nothing about, e.g. a
    feature that never differs between their paths and the alternatives)."""
    w = np.array([m.get(f"weight_{n}", np.nan) for n in learner_features], dtype=float)
    names = np.array(learner_features)
    parts = [f"{', '.join(names[hit])} at its {where} "
             f"({'nothing moved it: unknown' if where == 'middle' else BOUND_MEANS})"
             for where, hit in box.at_box(w).items() if hit.any()]
    return [f"  {label}  {'; '.join(parts)}"] if parts else []


BOUND_MEANS = "birl.lower/upper, not the demonstrations, set its size"
# below this acceptance rate a chain's samples are its few states, whatever R-hat says
STUCK_ACCEPTANCE = 0.01
# above this one, chains that do not agree creep: their steps are too small to go anywhere
# (proposal_step=1e-300 accepted every step, and "raise birl.max_samples" would not help)
CREEPING_ACCEPTANCE = 0.95
# print_summary: a weight that moved less than this share of the box's width over all
# iterations never left its start (MaxEnt's untouched weight moved 2e-6 of it, the others
# tenths)
UNMOVED_SHARE = 1e-5


def summary_text(m: dict, run_dir: str, learner_features: list[str],
                 box: Prior | None = None, given: list[str] | None = None,
                 unmoved: list[str] | None = None, learned_from: float | None = None) -> str:
    """The one screen a run ends with, from its metrics (the docs generator prints the same
    for the README's sample output). box: the learner's weight box, to say which learned
    weights lie at its bounds or its middle (None: the weights were given, not learned);
    given: for given weights, where they come from (`given_weights_origin`); unmoved: the
    learned weights no iteration moved from their start; learned_from: for given weights,
    how close the demonstrations they were learned from came to a person."""
    def fmt(key: str, spec: str = ".4f", unit: str = "") -> str:
        v = m.get(key)
        return "n/a" if v is None else format(v, spec) + unit

    def paths(prefix: str) -> str:
        return (f"crossings {fmt(prefix + 'relation_crossings', '.0f')}, intimate "
                f"{fmt(prefix + 'intimate_intrusion_m', '.2f')} m, personal "
                f"{fmt(prefix + 'personal_intrusion_m', '.2f')} m, min distance "
                f"{fmt(prefix + 'min_distance_to_person', '.2f', ' m')}, success "
                f"{fmt(prefix + 'success', '.2f')}")

    share = m.get("graph_demo_node_share", 0.0)
    def weight(n: str) -> str:  # sampling methods: the posterior mean ± its std
        std, w = m.get(f"weight_std_{n}"), m.get(f"weight_{n}")
        shown = "n/a" if w is None else f"{round(w, 3) + 0.0:.3f}"  # + 0.0: never "-0.000"
        return f"{n} {shown}" + ("" if std is None else f" ± {std:.3f}")

    label = "learned weights  " if given is None else "fixed weights    "
    lines = [f"BIRL-G run: {run_dir}",
             f"  {label}" + ", ".join(weight(n) for n in learner_features)]
    if box is not None:
        lines += weights_at_box(m, learner_features, box)
    if unmoved:
        lines.append(f"  not learned      {', '.join(unmoved)} never moved from where learning "
                     "started (a draw from the prior, see the log): the demonstrations say "
                     "nothing about it, or the method's steps are too small to move it")
    lines += given or []
    if "mcmc_acceptance_rate" in m:
        if m["mcmc_acceptance_rate"] < STUCK_ACCEPTANCE:  # the samples are the starts
            verdict = ("the chains barely moved: lower birl.proposal_step, or leave "
                       "birl.adapt=true to size the proposals")
        elif m.get("mcmc_rhat_max") is None and m.get("mcmc_chains", 1) < 2:
            verdict = "one chain: convergence untested; R-hat needs birl.n_chains ≥ 2"
        elif m.get("mcmc_rhat_max") is None:  # R-hat needs MIN_DRAWS samples of every chain
            verdict = (f"too few samples per chain to compare the chains (R-hat needs "
                       f"{MIN_DRAWS}): raise birl.n_samples")
        elif chains_agree([m["mcmc_rhat_max"]], [m.get("mcmc_ess_min", np.nan)]):
            verdict = "the chains agree"
        elif m["mcmc_acceptance_rate"] > CREEPING_ACCEPTANCE:
            verdict = ("the chains do not agree and nearly every step is accepted: the steps "
                       "are too small to explore; raise birl.proposal_step")
        else:
            verdict = (f"the chains do not agree yet: R-hat above {AGREED_RHAT:g} or ESS below "
                       f"{AGREED_ESS} after birl.max_samples samples per chain; raise it")
        lines.append(f"  posterior        R-hat max {fmt('mcmc_rhat_max', '.3f')}, ESS min "
                     f"{fmt('mcmc_ess_min', '.0f')}, acceptance "
                     f"{fmt('mcmc_acceptance_rate', '.2f')} ({verdict})")
    if "policy_loss" in m:
        lines.append(f"  policy loss      roadmap {fmt('policy_loss_ref')}, normalised "
                     f"{fmt('policy_loss_norm')}, graph {fmt('policy_loss')} (initial "
                     f"{fmt('policy_loss_initial')})")
        lines += worse_than_initial(m)
    if "heldout_count" in m:
        lines.append(f"  {'held out (' + fmt('heldout_count', '.0f') + ')':<17}Fréchet "
                     f"{fmt('heldout_frechet_m', '.2f')} m (shortest path "
                     f"{fmt('heldout_frechet_m_shortest', '.2f')} m), min-distance error "
                     f"{fmt('heldout_min_distance_error_m', '.2f')} m (shortest "
                     f"{fmt('heldout_min_distance_error_m_shortest', '.2f')} m)")
        if "heldout_frechet_m_max" in m:
            lines.append(f"                   worst held-out Fréchet "
                         f"{fmt('heldout_frechet_m_max', '.2f')} m (shortest path "
                         f"{fmt('heldout_frechet_m_shortest_max', '.2f')} m)")
        if "heldout_log_likelihood" in m:
            lines.append(f"                   log likelihood per demonstration "
                         f"{fmt('heldout_log_likelihood', '.2f')} (shortest path's reward "
                         f"{fmt('heldout_log_likelihood_shortest', '.2f')})")
        lines += heldout_no_better(m)
        lines += heldout_by_lattice(m)
        lines += heldout_worse(m)
    if m.get("demos_unreached", 0) > 0:
        lines.append(f"  warning          {fmt('demos_unreached', '.0f')} of "
                     f"{fmt('demos_count', '.0f')} demonstrations learned from do not reach the "
                     "goal (the log names them): the default learner reads them as walks to "
                     "the goal whose end was not recorded, eq. (2), PolicyWalk and MaxEnt as "
                     "walks that give the goal up")
    short = {where: m[key] for where, key in (("roadmap", "ref_success"), ("graph", "success"))
             if m.get(key) is not None and m[key] < 1}
    if short:
        lines.append("  warning          learned paths stop short of the goal (success "
                     + ", ".join(f"{where} {v:.2f}" for where, v in short.items())
                     + "): the distances below include paths that never arrive; see the "
                     "log's warnings and the paths (make view)")
    lines.append(f"  roadmap paths    {paths('ref_')}")
    lines.append(f"  graph paths      {paths('')}"
                 + (f" ({share:.0%} of its nodes are demonstration waypoints: these say "
                    "little)" if share > 0.5 else ""))
    ruder_than_demos = closer_than_demos(m, learned_from)
    lines += graph_less_polite(m, roadmap_ruder_than_demos=bool(ruder_than_demos))
    lines += ruder_than_demos
    lines += kept_by_lattice(m, learned_from)
    for name in [k[len("transfer_"):-len("_success")] for k in m
                 if k.startswith("transfer_") and k.endswith("_success")]:  # config order
        prefix = f"transfer_{name}_"
        loss = (f"normalised loss {fmt(prefix + 'policy_loss_norm')}, "
                if prefix + "policy_loss_norm" in m else "")
        lines.append(f"  transfer         {name} (roadmap): {loss}{paths(prefix)}")
    if "obstacle_collisions" in m:
        lines.append(f"  obstacles        collisions {fmt('obstacle_collisions', '.0f')}, min "
                     f"distance {fmt('min_distance_to_obstacle', '.2f')} m")
    if "frechet_to_demos" in m:
        lines.append(f"  vs demos         discrete Fréchet mean {fmt('frechet_to_demos', '.3f')} m "
                     "(on the graph that holds them)")
    lines.append("  stage seconds    " + ", ".join(
        f"{stage} {m[f'time_{stage}_s']:.2f}" for stage in STAGES if f"time_{stage}_s" in m))
    return "\n".join(lines)
