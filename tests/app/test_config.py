"""The app's config (pipeline/app/config.py): every config group option composes and
validates, an out-of-range value names its key, a key of another method is refused."""

import re

import pytest
from hydra.errors import ConfigCompositionException

from pipeline.app.config import load_settings as validate
from pipeline.errors import PipelineError
from tests.conftest import compose_config, run_app


@pytest.mark.parametrize("overrides", [
    [], ["scene=random"], ["scene=file", "scene.path=data/scenes/metropolis.json"],
    ["reward=rude"], ["expert=boltzmann"], ["expert=file", "expert.path=x.json"],
    ["graph=small"], ["graph.controller.kind=posq"], ["graph.weights=true"],
    ["graph.weights=[-1,-1,-1,-1,-1]"], ["birl=mcmc"],
])
def test_every_config_group_option_composes_and_validates(overrides):
    validate(compose_config(*overrides))


@pytest.mark.parametrize("override, key", [
    ("scene.body_radius=-0.1", "scene.body_radius"),
    ("reward.weights=[-1,-1]", "reward.weights"),
    ("stages=[scene,dance]", "stages"),
    ("mdp.gamma=1.5", "mdp.gamma"),
    ("scene=file", "scene.path"),
    ("graph.p_best=1.5", "graph.p_best"),
    ("graph.weights=[1,2]", "graph.weights"),
    ("graph.controller.kind=spline", "graph.controller.kind"),
    ("birl.prior.kind=cauchy", "birl.prior.kind"),
    ("birl.lower=[0,0,0,0]", "birl.lower"),
    ("birl.beta=-1", "birl.beta"),
    ("scene.robot_radius=-0.1", "scene.robot_radius"),
    ("scene=random scene.robot_radius=0", "scene.robot_radius"),
    ("expert=file expert.path=x.json expert.start_radius=0", "expert.start_radius"),
    ("expert=file expert.path=", "expert.path"),  # would read the working directory as a bag
    ("scene=file scene.path=", "scene.path"),
    ("from_run=", "from_run"),
    ("evaluate.transfer_scenes=[[a]]", "evaluate.transfer_scenes"),
    ("birl=mcmc birl.max_samples=10", "birl.max_samples"),  # fewer than n_samples
    # bounds that keep the arithmetic sane (found by fuzzing: petabyte arrays, zero durations,
    # a policy loss below 0 from round-off, an empty interval to sample persons from)
    ("reward.resolution=1e-12", "reward.resolution"),
    ("expert=planner expert.resolution=1e-12", "expert.resolution"),
    ("reward.rho_relation=1e12", "reward.rho_relation"),
    ("mdp.speed=1e12", "mdp.speed"),
    ("scene=random scene.width=1 scene.height=1", "scene.width"),
    ("scene=random scene.body_radius=100", "scene.width"),
    ("scene=random scene.seed=-1", "scene.seed"),
    # scenes the generator made and the validator refused, named against scene.mcap
    ("scene=random scene.border_margin=0", "scene.border_margin"),  # starts on the wall
    ("scene=random scene.formation_radius=1e-12", "scene.formation_radius"),  # one spot
    ("birl=policywalk birl.grid_step=5", "birl.grid_step"),  # no move inside the box
    ("graph.controller.k_beta=-3", "graph.controller.k_beta"),  # POSQ's, ignored by linear
    ("birl.n_iterations=1000000", "birl.n_iterations"),  # hours without a word
    ("birl.lower=[-1e12]", "birl.lower"),  # the weights never left their start
    ("graph.controller.kind=posq graph.controller.k_beta=inf", "graph.controller.k_beta"),
    ("birl=mcmc birl.thin=1000000", "birl.thin"),  # a 45 GB chain
    ("graph.controller.kind=posq graph.controller.dt=1e-12", "graph.controller.dt"),
    ("birl.prior.kind=gaussian birl.prior.mean=[-1e300]", "birl.prior.mean"),
    ("birl=fixed birl.from_run=", "birl.from_run"),
    ("graph.controller.max_speed=-1", "graph.controller.max_speed"),
    ("graph.controller.k_rho=0", "graph.controller.k_rho"),
    ("reward.features=[social,dance]", "reward.features"),
    ("reward.features=[social,length]", "reward.weights"),  # 4 weights for 2 features
])
def test_out_of_range_values_name_the_key(override, key):
    with pytest.raises(PipelineError) as err:
        validate(compose_config(*override.split()))
    message = str(err.value)
    assert message.startswith((f"config error: {key}=", f"config error: {key} is missing"))
    assert "\n" not in message


@pytest.mark.parametrize("overrides, key", [
    (["birl=maxent", "birl.alpha=3"], "birl.alpha"),  # a PolicyWalk key on MaxEnt
    (["birl=map", "birl.n_samples=10"], "birl.n_samples"),  # an MCMC key on the MAP method
    (["expert=optimal", "expert.beta=5"], "expert.beta"),  # a Boltzmann key on the optimal one
])
def test_a_key_of_another_method_is_refused(overrides, key):
    with pytest.raises(ConfigCompositionException, match=f"override '{key}'"):
        compose_config(*overrides)


def _options(group: str) -> list[str]:
    from tests.conftest import ROOT

    return sorted(p.stem for p in (ROOT / "conf" / group).glob("*.yaml"))


@pytest.mark.parametrize("method", _options("birl"))
def test_every_methods_command_line_defaults_are_its_python_defaults(method):
    """One source per default: conf/birl/<method>.yaml sets nothing the method's config
    dataclass does not already say, so `birl=<method>` and the class agree field by field."""
    from pipeline.irl import methods

    extra = ["birl.weights=[-1,-1,-1,-1]"] if method == "fixed" else []
    composed = validate(compose_config(f"birl={method}", *extra)).birl
    python = methods()[method].config(**({"weights": [-1, -1, -1, -1]} if extra else {}))
    assert composed == python


@pytest.mark.parametrize("expert", [e for e in _options("expert") if e != "file"])
def test_every_experts_command_line_defaults_are_its_python_defaults(expert):
    from pipeline.app.config import EXPERTS

    fixed = ["birl=fixed", "birl.weights=[-1,-1,-1,-1]"] if expert == "none" else []
    assert validate(compose_config(f"expert={expert}", *fixed)).expert == EXPERTS[expert]()


def test_the_mdp_presets_are_goal_reaching_and_the_papers_setting():
    from pipeline.core.graph_mdp import MDPParams

    assert validate(compose_config()).mdp == MDPParams()
    paper = validate(compose_config("mdp=paper")).mdp
    assert (paper.gamma, paper.time_cost, paper.dead_end_value) == (0.95, 0.0, -10.0)


def test_the_old_spelling_of_n_starts_still_works_with_a_warning(caplog):
    with caplog.at_level("WARNING", logger="pipeline"):
        settings = validate(compose_config("expert.n_demos=3"))
    assert settings.expert.n_starts == 3
    assert "expert.n_demos is deprecated and will be removed: use expert.n_starts" in caplog.text


def test_a_policywalk_grid_step_that_leaves_the_chain_no_move_in_the_box_is_refused():
    """A step of 5 in a box of side 1: every proposal left the box, and the chain stayed at
    its start with exit 0."""
    with pytest.raises(PipelineError, match=re.escape(
            "config error: birl.grid_step=0.6 is not allowed (allowed: at most half the "
            "weight box's narrowest side (0.5))")):
        validate(compose_config("birl=policywalk", "birl.grid_step=0.6"))
    assert validate(compose_config("birl=policywalk", "birl.grid_step=0.5")).birl.grid_step == 0.5


@pytest.mark.parametrize("overrides, message", [
    (["expert.n_demos=3", "expert.n_starts=5"], "expert.n_demos=3 is not allowed (allowed: "
     "expert.n_starts alone: expert.n_demos is its old name and both were given)"),
    (["birl=mcmc", "birl.step=0.1", "birl.proposal_step=0.2"], "birl.step=0.1 is not allowed"),
    (["birl=policywalk", "birl.step=0.1", "birl.grid_step=0.2"], "birl.step=0.1 is not allowed"),
    (["birl.lr_level=0.1", "birl.test_level=0.2"], "birl.lr_level=0.1 is not allowed"),
])
def test_an_old_spelling_given_with_its_new_name_is_refused(overrides, message):
    """The old spelling used to win silently over the new name given beside it."""
    with pytest.raises(PipelineError, match=re.escape(f"config error: {message}")):
        validate(compose_config(*overrides))


def test_holding_out_demonstrations_of_no_demonstrator_is_refused():
    """expert=none evaluate.holdout=all ran and warned that no start has two demonstrations."""
    with pytest.raises(PipelineError, match=re.escape(
            "config error: evaluate.holdout=all is not allowed (allowed: null with expert=none "
            "(it has no demonstrations to hold out")):
        validate(compose_config("expert=none", "birl=fixed", "birl.weights=[-1,-1,-1,-1,-1]",
                                "evaluate.holdout=all"))


@pytest.mark.parametrize("overrides, message", [
    (["expert.n_demos=0"], "expert.n_demos=0 is not allowed (allowed: an integer >= 1)"),
    (["birl=mcmc", "birl.step=-1"], "birl.step=-1.0 is not allowed"),
    (["birl=policywalk", "birl.step=0"], "birl.step=0.0 is not allowed"),
    (["birl.lr_level=2"], "birl.lr_level=2.0 is not allowed"),
    (["expert.n_starts=0"], "expert.n_starts=0 is not allowed"),
])
def test_a_bad_value_is_refused_under_the_name_it_was_given(overrides, message):
    """An old spelling's value moves to the new name before it is checked; the refusal
    named the new key, which the user had not written."""
    with pytest.raises(PipelineError, match=re.escape(f"config error: {message}")):
        validate(compose_config(*overrides))


@pytest.mark.parametrize("overrides, expected", [
    ([], ["relation", "social", "goal_deviation", "length", "crossing"]),
    (["expert=planner"], ["relation", "social", "goal_deviation", "length", "crossing"]),
    (["expert=planner", "birl.features=[relation,social,length]"],
     ["relation", "social", "length"]),
])
def test_the_learners_default_features_are_the_rewards_and_crossing(overrides, expected):
    assert validate(compose_config(*overrides)).learner_features == expected


def test_config_errors_show_numbers_as_typed_not_numpy_reprs():
    """birl.upper=[1] with mdp.gamma=1 is checked on the prior's numpy bounds."""
    with pytest.raises(PipelineError) as err:
        validate(compose_config("mdp.gamma=1", "birl.upper=[1]"))
    assert "birl.upper=[1.0, 1.0, 1.0, 1.0, 1.0] is not allowed" in str(err.value)
    assert "np." not in str(err.value)


def test_a_single_held_out_subject_without_brackets_is_shown_the_list_form():
    with pytest.raises(PipelineError) as err:
        validate(compose_config("evaluate.holdout=sub3"))
    assert str(err.value).endswith("(one subject: 'evaluate.holdout=[sub3]'))")
    with pytest.raises(PipelineError) as err:  # a number is not taken for an id
        validate(compose_config("evaluate.holdout=7"))
    assert "one subject" not in str(err.value)


def test_a_denoise_that_is_no_bool_is_one_line_naming_it():
    result = run_app("expert=file", "expert.path=x.json", "expert.denoise=maybe",
                     "stages=[scene]")
    assert result.returncode != 0
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "expert.denoise=maybe" in lines[0] and "not a valid bool" \
        in lines[0]


def test_a_deployment_grows_its_graph_under_the_weights_it_deploys():
    """birl=fixed: the graph grows under the deployed weights on every learner feature but
    the extras (crossing), whatever this run's reward.features (a deployment has no true
    reward); learning grows under the prior mean on the reward's features only."""
    from pipeline.app.build import growth_weights

    features = "[relation,crossing,social@0.8,gaussian,goal_deviation,length]"
    weights = "[-1,-0.5,-0.4,-0.3,-0.6,-0.1]"
    deployed = validate(compose_config("expert=none", "birl=fixed", f"birl.features={features}",
                                       f"birl.weights={weights}"))
    w, source = growth_weights(deployed, None)
    assert source == "fixed" and w.tolist() == [-1, 0, -0.4, -0.3, -0.6, -0.1]
    learning = validate(compose_config(f"birl.features={features}"))
    w, source = growth_weights(learning, None)
    assert source == "prior_mean" and w[1] == w[2] == w[3] == 0 and w[0] != 0


@pytest.mark.parametrize("overrides, on_graph", [
    ([], False), (["birl.likelihood=paper"], True), (["birl.alternatives=graph"], True),
    (["birl.likelihood=robust"], False), (["birl=mcmc"], True), (["birl=policywalk"], True),
    (["birl=maxent"], False), (["birl=fixed", "birl.weights=[-1,-1,-1,-1,-1]"], False),
])
def test_each_method_says_whether_it_compares_the_demonstrations_with_the_graphs_paths(
        overrides, on_graph):
    # the graph stage warns when the demonstrations' waypoints fill the graph for these; a
    # new method (IRLConfig's default) is one unless it says otherwise
    from pipeline.irl.base import IRLConfig

    assert validate(compose_config(*overrides)).birl.compares_with_graph_paths is on_graph
    assert IRLConfig().compares_with_graph_paths is True
