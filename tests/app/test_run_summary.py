"""The run summary's held-out warnings, from metrics alone: the learned paths against the
shortest paths on the held-out demonstrations, a tie within HELDOUT_TIE_M."""

import pytest

from pipeline.app.run_summary import HELDOUT_TIE_M, summary_text

AS_FAR = "as far from the held-out demonstrations as the shortest paths are (within 0.05 m)"
WORSE = "predicts them worse than no reward does"
WORSE_PASSING = "predicts how closely they pass people worse than no reward does"


def summary(frechet: float, frechet_shortest: float, error: float,
            error_shortest: float) -> str:
    m = {"heldout_count": 9.0, "heldout_frechet_m": frechet,
         "heldout_frechet_m_shortest": frechet_shortest,
         "heldout_min_distance_error_m": error,
         "heldout_min_distance_error_m_shortest": error_shortest}
    return summary_text(m, "RUN", ["relation", "social", "goal_deviation", "length"])


def test_a_difference_below_the_tie_is_no_better_not_worse():
    """A hall's learned paths were 7 mm farther from the held-out walks than the shortest
    (2.49 m each, as printed): the summary called them "worse than no reward". They are
    as far, within the tie."""
    assert HELDOUT_TIE_M == 0.05  # the message's "within 0.05 m"
    out = summary(2.4949, 2.4881, 0.20, 0.21)
    assert AS_FAR in out
    assert WORSE not in out and WORSE_PASSING not in out
    assert AS_FAR in summary(1.0, 1.0, 0.3, 0.3)  # exactly as far


def test_worse_beyond_the_tie_is_said_per_measure_and_better_is_not_as_far():
    out = summary(2.6, 2.4881, 0.20, 0.21)
    assert WORSE in out and WORSE_PASSING not in out and AS_FAR not in out
    out = summary(2.49, 2.49, 0.30, 0.21)
    assert WORSE_PASSING in out and WORSE not in out and AS_FAR not in out
    out = summary(0.40, 2.49, 0.20, 0.21)  # better in Fréchet, a tie in the other
    assert AS_FAR not in out and WORSE not in out and WORSE_PASSING not in out


def test_a_difference_of_exactly_the_tie_is_a_tie():
    """0.14 m against 0.09 m is a difference of 0.05 m as printed, the tie itself, but
    0.14 - 0.09 is 0.05000000000000002 and 0.09 + 0.05 is 0.14: the tie's rule (|a - b| >
    0.05) and the worse rule (a > b + 0.05) each said no, and the summary said neither "as
    far" nor "worse". Within the tie, with a rounding's slack, is a tie."""
    out = summary(0.14, 0.09, 0.20, 0.20)
    assert AS_FAR in out and WORSE not in out
    out = summary(0.20, 0.20, 0.14, 0.09)
    assert AS_FAR in out and WORSE_PASSING not in out
    assert WORSE in summary(0.1401, 0.09, 0.20, 0.20)  # past it: worse


def test_a_tie_on_the_lattice_is_no_difference_the_lattice_made():
    """The hall's 7 mm lag, a tie ("as far ... within 0.05 m"), was followed by "pulled taut
    ... no worse than the shortest paths: the difference above is the lattice's doing",
    where the line above had said there was none. Only a lead or a lag beyond the tie
    turns; one that does (0.71 m against 0.56 m, 0.03 m each pulled taut) is still said."""
    taut = {"heldout_frechet_m_taut": 2.40, "heldout_frechet_m_shortest_taut": 2.41,
            "heldout_min_distance_error_m_taut": 0.20,
            "heldout_min_distance_error_m_shortest_taut": 0.21}
    m = {"heldout_count": 9.0, "heldout_frechet_m": 2.4949, "heldout_frechet_m_shortest": 2.4881,
         "heldout_min_distance_error_m": 0.20, "heldout_min_distance_error_m_shortest": 0.21,
         **taut}
    out = summary_text(m, "RUN", ["relation"])
    assert AS_FAR in out and "lattice's doing" not in out
    m.update(heldout_min_distance_error_m=0.71, heldout_min_distance_error_m_shortest=0.56,
             heldout_min_distance_error_m_taut=0.03,
             heldout_min_distance_error_m_shortest_taut=0.03)
    out = summary_text(m, "RUN", ["relation"])
    assert "no worse (min-distance error 0.03 m against 0.03 m) than the shortest paths: the " \
        "difference above is the lattice's doing" in out


POSTERIOR_CASES = [
    # (metrics, the verdict in parentheses): each rule of the posterior line, at its bounds
    ({"mcmc_acceptance_rate": 0.005, "mcmc_rhat_max": 1.0, "mcmc_ess_min": 500.0},
     "the chains barely moved: lower birl.proposal_step, or leave birl.adapt=true to size "
     "the proposals"),
    ({"mcmc_acceptance_rate": 0.3, "mcmc_chains": 1},
     "one chain: convergence untested; R-hat needs birl.n_chains ≥ 2"),
    ({"mcmc_acceptance_rate": 0.3, "mcmc_chains": 4},
     "too few samples per chain to compare the chains (R-hat needs 4): raise birl.n_samples"),
    ({"mcmc_acceptance_rate": 0.01, "mcmc_rhat_max": 1.05, "mcmc_ess_min": 100.0},
     "the chains agree"),
    ({"mcmc_acceptance_rate": 0.96, "mcmc_rhat_max": 1.3, "mcmc_ess_min": 500.0},
     "the chains do not agree and nearly every step is accepted: the steps are too small to "
     "explore; raise birl.proposal_step"),
    ({"mcmc_acceptance_rate": 0.95, "mcmc_rhat_max": 1.02, "mcmc_ess_min": 99.0},
     "the chains do not agree yet: R-hat above 1.05 or ESS below 100 after birl.max_samples "
     "samples per chain; raise it"),
]


@pytest.mark.parametrize("metrics, verdict", POSTERIOR_CASES)
def test_the_posterior_line_gives_the_verdict_of_its_rule(metrics, verdict):
    """Stuck below an acceptance of 0.01; one chain, or too few samples, without R-hat; agreed
    at R-hat <= 1.05 and ESS >= 100 (both bounds included); creeping only above 0.95."""
    out = summary_text(metrics, "RUN", ["relation"])
    line = next(x for x in out.splitlines() if x.startswith("  posterior        "))
    assert line.endswith(f"({verdict})"), line
    rhat = metrics.get("mcmc_rhat_max")
    assert f"R-hat max {'n/a' if rhat is None else format(rhat, '.3f')}, " in line


def test_a_lead_on_the_lattice_that_pulled_taut_is_gone_is_the_lattice_s_doing():
    """The docstring's lobby: learned paths 0.6 m nearer the held-out walks than the shortest
    on the lattice (a lead beyond the tie), 1.07 m against 1.07 m pulled taut (no lead left:
    exactly level counts as gone) are said to be "no better" than the shortest paths; a
    lead that pulled taut is still one (1.06 m against 1.07 m) is not."""
    m = {"heldout_count": 9.0, "heldout_frechet_m": 0.9, "heldout_frechet_m_shortest": 1.5,
         "heldout_frechet_m_taut": 1.07, "heldout_frechet_m_shortest_taut": 1.07,
         "heldout_min_distance_error_m": 0.20, "heldout_min_distance_error_m_shortest": 0.20,
         "heldout_min_distance_error_m_taut": 0.20,
         "heldout_min_distance_error_m_shortest_taut": 0.20}
    out = summary_text(m, "RUN", ["relation"])
    assert "held-out demonstrations no better (Fréchet 1.07 m against 1.07 m) than the " \
        "shortest paths: the difference above is the lattice's doing" in out
    assert "no worse" not in out and AS_FAR not in out
    m["heldout_frechet_m_taut"] = 1.06
    assert "lattice's doing" not in summary_text(m, "RUN", ["relation"])
