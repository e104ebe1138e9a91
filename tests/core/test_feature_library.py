"""The feature library (DESIGN §4 "More features") against hand computations.

Straight paths past persons, groups and walls have closed-form integrals. The density
features are integrated by the midpoint rule with sub-steps k <= resolution, whose error
on a straight path of length L is at most L k² max|f''| / 24 on the smooth parts plus
Δ k² / 8 for every kink of slope jump Δ (a sub-step containing the kink of Δ·max(0, t − t0)
is off by at most Δ k² / 8). `midpoint_bound` is that bound; each test below derives
max|f''| and the kinks of its integrand, and the bound is far below what a wrong sign or
factor would change.
"""

import dataclasses
import math

import numpy as np
import pytest
from scipy.special import erf

from pipeline.core.features import (
    FEATURE_KINDS,
    FEATURE_NAMES,
    GAUSSIAN_CUTOFF,
    PARAMETER_FIELD,
    Feature,
    FeatureModel,
    FeatureParams,
    social_groups,
)
from pipeline.core.obstacles import ObstacleMap, OccupancyGrid
from pipeline.core.params import ParameterError
from pipeline.core.roadmap import lattice_graph
from pipeline.core.world import Room, scene_from_dict
from pipeline.inputs.scene_file import load_scene_file
from tests.conftest import ROOT

K = FeatureParams().resolution  # the default sub-step bound, 0.05 m
EVERY_LOCAL = ("relation", "intimate", "social@0.8", "social", "social_squared", "gaussian",
               "front", "group_space")


def midpoint_bound(length, f2_max, kinks=(), k=K):
    """Largest error of the midpoint rule with sub-steps <= k (module docstring)."""
    return length * k**2 * f2_max / 24 + sum(kinks) * k**2 / 8


def model(persons, features, headings=None, relations=(), obstacles=None, resolution=K,
          **params):
    xy = np.array(persons, float).reshape(-1, 2)
    pairs = np.array(relations, int).reshape(-1, 2)
    return FeatureModel(xy[pairs[:, 0]], xy[pairs[:, 1]], xy, np.array([100.0, 100.0]),
                        resolution=resolution, names=tuple(features),
                        headings=None if headings is None else np.array(headings, float),
                        groups=social_groups(len(xy), pairs), obstacles=obstacles, **params)


def line(x0, y0, x1, y1):
    return np.array([[x0, y0], [x1, y1]], float)


def hinge_integral(rho, h, t0=-math.inf, t1=math.inf):
    """∫_{t0}^{t1} max(0, ρ − √(t² + h²)) dt for h > 0: with a = √(ρ² − h²), the
    antiderivative ρt − (t√(t²+h²) + h² asinh(t/h)) / 2 between the clipped limits."""
    a = math.sqrt(rho**2 - h**2)

    def antiderivative(t):
        t = min(max(t, -a), a)
        return rho * t - 0.5 * (t * math.hypot(t, h) + h**2 * math.asinh(t / h))
    return antiderivative(t1) - antiderivative(t0)


def hinge_bound(rho, h):
    """|f''| = h²/d³ <= 1/h on the 2a where f > 0; kinks at ±a of slope a/ρ."""
    a = math.sqrt(rho**2 - h**2)
    return midpoint_bound(2 * a, 1 / h, [a / rho, a / rho])


# -- names and parameters ------------------------------------------------------------------

def test_default_feature_set_is_the_four_of_the_paper():
    assert FeatureParams().features == ["relation", "social", "goal_deviation", "length"]
    assert list(FEATURE_NAMES) == FeatureParams().features
    assert [f.kind for f in FeatureParams().selected()] == list(FEATURE_NAMES)


def test_name_at_value_sets_the_parameter_and_plain_names_take_the_params():
    params = FeatureParams(features=["relation@0.8", "social@0.8", "social", "intimate",
                                     "gaussian", "gaussian@0.5", "front", "front@2",
                                     "group_space@0.5", "group_space", "obstacle@0.3",
                                     "obstacle", "wall@0.3", "wall", "goal_deviation", "length"],
                           rho_personal=1.5, sigma=0.7, rho_group=0.2, rho_obstacle=0.4)
    got = [(f.name, f.kind, f.value) for f in params.selected()]
    assert got[:-2] == [
        ("relation@0.8", "relation", 0.8), ("social@0.8", "social", 0.8),
        ("social", "social", 1.5), ("intimate", "social", 0.45),
        ("gaussian", "gaussian", 0.7), ("gaussian@0.5", "gaussian", 0.5),
        ("front", "front", 1.5), ("front@2", "front", 2.0),
        ("group_space@0.5", "group_space", 0.5), ("group_space", "group_space", 0.2),
        ("obstacle@0.3", "obstacle", 0.3), ("obstacle", "obstacle", 0.4),
        ("wall@0.3", "wall", 0.3), ("wall", "wall", 0.4)]
    assert [f.kind for f in params.selected()[-2:]] == ["goal_deviation", "length"]
    assert all(math.isnan(f.value) for f in params.selected()[-2:])


@pytest.mark.parametrize("features, culprit", [
    (["relation", "socal"], "'socal' is not a feature"),
    (["social@"], "length in metres from 0.001 to 10000"),
    (["social@abc"], "length in metres from 0.001 to 10000"),
    (["social@-1"], "length in metres from 0.001 to 10000"),
    (["social@0"], "length in metres from 0.001 to 10000"),
    (["gaussian@inf"], "length in metres from 0.001 to 10000"),
    (["front@nan"], "length in metres from 0.001 to 10000"),
    (["social@0.8@1"], "length in metres from 0.001 to 10000"),
    # as reward.rho_personal: a 1e308 m hinge overflowed the learner's linear algebra
    (["social@1e308"], "length in metres from 0.001 to 10000"),
    (["gaussian@10000.001"], "length in metres from 0.001 to 10000"),
    (["length@1"], "length takes no @VALUE"),
    (["goal_deviation@2"], "goal_deviation takes no @VALUE"),
    (["intimate@0.3"], "intimate takes no @VALUE"),
    (["@1.0"], "'' is not a feature"),
    ([], "at least one"),
    ([3], "3 is not a name"),
    (["social", "social@1.2"], "'social@1.2' is the same feature as 'social'"),
    (["social@0.8", "social@0.80"], "'social@0.80' is the same feature as 'social@0.8'"),
    (["social@0.45", "intimate"], "'intimate' is the same feature as 'social@0.45'"),
    (["front@1.2", "front"], "'front' is the same feature as 'front@1.2'"),
    (["social_squared@-1"], "length in metres from 0.001 to 10000"),
    (["social_squared", "social_squared@1.2"],
     "'social_squared@1.2' is the same feature as 'social_squared'"),
    (["length", "length"], "'length' is the same feature as 'length'"),
    (["wall@-0.5"], "length in metres from 0.001 to 10000"),
    (["wall", "wall@0.5"], "'wall@0.5' is the same feature as 'wall'"),
])
def test_bad_feature_names_are_refused_naming_the_field_and_the_allowed_names(features,
                                                                             culprit):
    with pytest.raises(ParameterError) as err:
        FeatureParams(features=features)
    assert err.value.field == "features"
    assert culprit in err.value.allowed
    assert all(repr(kind) in err.value.allowed for kind in FEATURE_KINDS)


def test_a_duplicate_depends_on_the_resolved_default():
    FeatureParams(features=["social", "social@1.0"])  # ρ_p = 1.2: two radii
    with pytest.raises(ParameterError, match="same feature"):
        FeatureParams(features=["social", "social@1.0"], rho_personal=1.0)
    FeatureParams(features=["social", "front"])  # same radius, different features


@pytest.mark.parametrize("field", ["sigma", "rho_group", "rho_obstacle"])
@pytest.mark.parametrize("value", [0.0, -0.3, math.inf, math.nan])
def test_new_constants_are_range_checked(field, value):
    with pytest.raises(ParameterError) as err:
        FeatureParams(**{field: value})
    assert err.value.field == field
    with pytest.raises(ParameterError):
        model([(0, 0)], ["social"], **{field: value})


def test_a_model_refuses_bad_names_too():
    with pytest.raises(ParameterError, match="'socal' is not a feature"):
        model([(0, 0)], ["socal"])


# -- the hinges: social at any radius, intimate --------------------------------------------

@pytest.mark.parametrize("name, rho, h", [("intimate", 0.45, 0.3), ("social@0.8", 0.8, 0.5),
                                          ("social", 1.2, 0.5), ("social@2.0", 2.0, 1.0)])
def test_hinge_past_a_person_at_known_distance(name, rho, h):
    fm = model([(0, 0)], [name])
    got = fm.polyline(line(-3, h, 3, h))[0]
    assert abs(got - hinge_integral(rho, h)) <= hinge_bound(rho, h)
    assert hinge_bound(rho, h) < 0.02 * hinge_integral(rho, h)  # sees a wrong factor


def squared_hinge_integral(rho, h):
    """∫ max(0, ρ − √(t² + h²))² / ρ dt over the line at distance h < ρ: with
    a = √(ρ² − h²), expanding the square and ∫_{−a}^{a} √(t² + h²) dt = aρ + h² asinh(a/h),
    (2a³/3 + 2ah² − 2ρh² asinh(a/h)) / ρ."""
    a = math.sqrt(rho**2 - h**2)
    return (2 * a**3 / 3 + 2 * a * h**2 - 2 * rho * h**2 * math.asinh(a / h)) / rho


@pytest.mark.parametrize("name, rho, h", [("social_squared", 1.2, 0.5),
                                          ("social_squared@0.8", 0.8, 0.3),
                                          ("social_squared@2.0", 2.0, 1.4)])
def test_squared_hinge_past_a_person_at_known_distance(name, rho, h):
    fm = model([(0, 0)], [name, "social@" + str(rho)])
    got, linear = fm.polyline(line(-3, h, 3, h))
    # midpoint rule: |f''| <= (2/ρ)(1 + ρ/h) on the 2a where f > 0, f' continuous
    a = math.sqrt(rho**2 - h**2)
    bound = midpoint_bound(2 * a, 2 / rho * (1 + rho / h))
    assert abs(got - squared_hinge_integral(rho, h)) <= bound
    assert bound < 0.02 * squared_hinge_integral(rho, h)  # sees a wrong factor
    assert 0 < got < linear  # depth/ρ < 1: the square weighs every metre less than the hinge


def test_the_squared_hinge_grows_with_depth_faster_than_the_hinge():
    # Passing twice as deep costs the hinge about three times as much here, the square more.
    fm = model([(0, 0)], ["social", "social_squared"])
    shallow, deep = fm.polyline(line(-3, 0.9, 3, 0.9)), fm.polyline(line(-3, 0.6, 3, 0.6))
    assert deep[1] / shallow[1] > deep[0] / shallow[0] > 1


def test_a_family_of_hinges_side_by_side():
    # Passing at 1.0 m: only the hinges wider than 1 m see the person.
    fm = model([(0, 0)], ["social@0.8", "social", "social@2.0", "intimate"])
    f = fm.polyline(line(-3, 1.0, 3, 1.0))
    assert f[0] == 0.0 and f[3] == 0.0
    assert abs(f[1] - hinge_integral(1.2, 1.0)) <= hinge_bound(1.2, 1.0)
    assert abs(f[2] - hinge_integral(2.0, 1.0)) <= hinge_bound(2.0, 1.0)


def test_hinge_takes_the_nearest_person():
    # Two persons on one side of the path, 0.5 m and 0.9 m from its line: the nearer one is
    # nearer at every point and alone sets max(0, ρ − min_i d_i).
    fm = model([(0, 0), (0, -0.4)], ["social"])
    got = fm.polyline(line(-3, 0.5, 3, 0.5))[0]
    assert abs(got - hinge_integral(1.2, 0.5)) <= hinge_bound(1.2, 0.5)


def test_relation_is_exact_across_a_link_end():
    # Link (0,0)-(4,0); path (3,−0.3) → (5,0.3) of length L = √4.36 leaves the link's span
    # at x = 4 (s = 1/2), where the integrand jumps from 0.6 to 0: relation =
    # L ∫_0^{1/2} (0.6 − (0.3 − 0.6 s)) ds = 0.225 L, whatever the sampling resolution.
    path = line(3, -0.3, 5, 0.3)
    for resolution in (0.1, 0.05, 0.01):
        fm = model([(0, 0), (4, 0)], ["relation", "relation@0.8"], relations=[(0, 1)],
                   resolution=resolution)
        got = fm.polyline(path)
        exact = [0.225 * math.sqrt(4.36), math.sqrt(4.36) * (0.5 * 0.5 + 0.6 * 0.125)]
        np.testing.assert_allclose(got, exact, rtol=1e-12)
    # Crossing the middle at right angles: ∫ max(0, ρ − |y|) dy = ρ².
    np.testing.assert_allclose(fm.polyline(line(2, -2, 2, 2)), [0.36, 0.64], rtol=1e-12)


# -- gaussian ------------------------------------------------------------------------------

def gaussian_integral(sigma, h, t0, t1):
    """∫_{t0}^{t1} exp(−(t² + h²) / 2σ²) dt = e^{−h²/2σ²} σ √(π/2) [erf(t/σ√2)]."""
    s = sigma * math.sqrt(2)
    return math.exp(-h**2 / (2 * sigma**2)) * sigma * math.sqrt(math.pi / 2) * (
        erf(t1 / s) - erf(t0 / s))


@pytest.mark.parametrize("name, sigma", [("gaussian", 0.8), ("gaussian@0.5", 0.5)])
def test_gaussian_along_a_line_through_the_person_is_an_erf_window(name, sigma):
    fm = model([(0, 0)], [name])
    got = fm.polyline(line(-3, 0, 2, 0))[0]
    exact = gaussian_integral(sigma, 0, -3, 2)
    # |f''| <= 1/σ²; the dropped tail adds at most 5 m × 1e-12.
    bound = midpoint_bound(5, 1 / sigma**2) + 5 * GAUSSIAN_CUTOFF
    assert abs(got - exact) <= bound < 2e-3 * exact


def test_gaussian_sums_over_persons():
    fm = model([(0, 0), (1, 0)], ["gaussian"])
    got = fm.polyline(line(-3, 0.5, 4, 0.5))[0]
    exact = (gaussian_integral(0.8, 0.5, -3, 4) + gaussian_integral(0.8, 0.5, -4, 3))
    amplitude = math.exp(-0.5**2 / (2 * 0.8**2))
    assert abs(got - exact) <= midpoint_bound(7, 2 * amplitude / 0.8**2)


def test_gaussian_is_local_beyond_its_cutoff():
    # The term at 7.5 σ is below 1e-12 of the peak and dropped: exactly 0 there.
    fm = model([(0, 0)], ["gaussian"])
    assert fm.polyline(line(-3, 7.5 * 0.8, 3, 7.5 * 0.8))[0] == 0.0
    assert 0 < fm.polyline(line(-3, 7.4 * 0.8, 3, 7.4 * 0.8))[0] < 1e-11


# -- front ---------------------------------------------------------------------------------

def front_ahead(rho, h, t0, t1):
    """∫ (ρ − d) h/d dt along the line x = h ahead of a person facing +x:
    G(t) = ρh asinh(t/h) − h t between the limits clipped to ±a."""
    a = math.sqrt(rho**2 - h**2)

    def g(t):
        t = min(max(t, -a), a)
        return rho * h * math.asinh(t / h) - h * t
    return g(t1) - g(t0)


def test_front_ahead_behind_and_sideways():
    rho, h = 1.2, 0.5
    a = math.sqrt(rho**2 - h**2)
    fm = model([(0, 0)], ["front", "social"], headings=[0.0])  # facing +x
    # Ahead: f = ρh/d − h, |f''| <= ρ/h², kinks at ±a of slope ha/ρ².
    ahead = fm.polyline(line(h, -3, h, 3))
    exact = front_ahead(rho, h, -3, 3)
    assert abs(ahead[0] - exact) <= midpoint_bound(2 * a, rho / h**2, [h * a / rho**2] * 2)
    assert ahead[0] < ahead[1]  # the cosine weight < 1 off the heading
    # Behind: the cosine is negative everywhere, the hinge is not.
    behind = fm.polyline(line(-h, -3, -h, 3))
    assert behind[0] == 0.0 and behind[1] > 0.5
    # Sideways along y = h: only x > 0 counts, ∫_0^a (ρ − d) t/d dt = (ρ − h)² / 2;
    # |f''| = 3ρh²t/d⁵ <= 0.8587 ρ/h², kinks at 0 (slope ρ/h − 1) and a (1 − h²/ρ²).
    side = fm.polyline(line(-3, h, 3, h))[0]
    bound = midpoint_bound(a, 0.8587 * rho / h**2, [rho / h - 1, 1 - h**2 / rho**2])
    assert abs(side - (rho - h)**2 / 2) <= bound < 1e-2 * (rho - h)**2 / 2


def test_front_turns_with_the_heading_and_takes_its_radius():
    # Facing +y (θ = π/2): the line y = h is ahead, y = −h behind; front@0.8 at 0.8 m.
    fm = model([(0, 0)], ["front@0.8"], headings=[math.pi / 2])
    ahead = fm.polyline(line(-3, 0.5, 3, 0.5))[0]
    a = math.sqrt(0.8**2 - 0.5**2)
    bound = midpoint_bound(2 * a, 0.8 / 0.5**2, [0.5 * a / 0.8**2] * 2)
    assert abs(ahead - front_ahead(0.8, 0.5, -3, 3)) <= bound
    assert fm.polyline(line(-3, -0.5, 3, -0.5))[0] == 0.0


def test_front_takes_the_largest_weighted_hinge_not_the_sum():
    # Two persons at (0, ±s) facing +x, path x = h. For y > 0 the upper one is nearer and
    # more ahead, so its term is the larger: front = 2 ∫_{−s}^{a} of the single-person
    # integrand = 2 (G(a) − G(−s)). A sum over persons would give 2 × front_ahead(−3, 3).
    rho, h, s = 1.2, 0.5, 0.3
    a = math.sqrt(rho**2 - h**2)
    fm = model([(0, s), (0, -s)], ["front"], headings=[0.0, 0.0])
    got = fm.polyline(line(h, -3, h, 3))[0]
    exact = 2 * front_ahead(rho, h, -s, 3)
    kink_at_0 = 2 * rho * h * s / (s**2 + h**2) ** 1.5  # where the two terms swap
    bound = midpoint_bound(2 * (a + s), rho / h**2, [h * a / rho**2] * 2 + [kink_at_0])
    assert abs(got - exact) <= bound
    assert 2 * front_ahead(rho, h, -3, 3) - exact > 100 * bound


def test_front_is_not_the_nearest_persons_alone():
    # A at the origin faces away from the path x = 0.5 (behind A: 0); B at (−0.3, 0), 0.8 m
    # from the path, faces it. B's weighted hinge counts although A is nearer everywhere.
    rho, h = 1.2, 0.8
    a = math.sqrt(rho**2 - h**2)
    fm = model([(0, 0), (-0.3, 0)], ["front"], headings=[math.pi, 0.0])
    got = fm.polyline(line(0.5, -3, 0.5, 3))[0]
    exact = front_ahead(rho, h, -3, 3)
    assert abs(got - exact) <= midpoint_bound(2 * a, rho / h**2, [h * a / rho**2] * 2)
    assert exact > 0.4


def test_front_reads_headings_from_the_scene():
    scene = scene_from_dict({
        "room": {"x_min": -5, "y_min": -5, "x_max": 5, "y_max": 5},
        "persons": [{"id": 1, "x": 0, "y": 0, "vx": 0.0, "vy": 1.0}],  # θ = atan2(1, 0)
        "starts": [[-4, -4]], "goal": [4, 4]})
    fm = FeatureModel.from_scene(scene, FeatureParams(features=["front"]))
    assert fm.polyline(line(-3, 0.5, 3, 0.5))[0] > 0.1
    assert fm.polyline(line(-3, -0.5, 3, -0.5))[0] == 0.0


# -- group_space ---------------------------------------------------------------------------

TRIANGLE = [(0, 0), (2, 0), (1, 3)]  # centre (1, 1), member distances √2, √2, 2


def test_groups_are_connected_components_of_two_or_more():
    # 0-1 and 1-2 join the triangle (2 relations, 3 members); 3-4 a pair; 5 alone.
    pairs = np.array([[0, 1], [2, 1], [4, 3]])
    assert social_groups(6, pairs) == ((0, 1, 2), (3, 4))
    assert social_groups(3, np.zeros((0, 2))) == ()


def test_group_space_of_a_group_of_three():
    r_g = (2 * math.sqrt(2) + 2) / 3 + 0.3  # mean member distance to (1, 1) plus ρ_group
    persons = TRIANGLE + [(10, 0), (11, 0), (20, 0)]
    relations = [(0, 1), (1, 2), (3, 4)]
    fm = model(persons, ["group_space", "group_space@0.5", "social"], relations=relations)
    h = 0.4
    f = fm.polyline(line(-3, 1 + h, 5, 1 + h))
    assert abs(f[0] - hinge_integral(r_g, h)) <= hinge_bound(r_g, h)
    assert abs(f[1] - hinge_integral(r_g + 0.2, h)) <= hinge_bound(r_g + 0.2, h)
    # The pair: centre (10.5, 0), r = 0.5 + 0.3; along its axis ∫ max(0, 0.8 − |t|) = 0.64,
    # exact for the midpoint rule on the linear pieces up to the kinks at 0 (2) and ±0.8 (1).
    pair = fm.polyline(line(9, 0, 12, 0))[0]
    assert abs(pair - 0.64) <= midpoint_bound(1.6, 0, [1, 2, 1])
    # Sum over groups: one path through both o-spaces.
    both = fm.polyline(np.array([[-3, 1 + h], [5, 1 + h], [9, 0], [12, 0]]))[0]
    link = fm.polyline(line(5, 1 + h, 9, 0))[0]
    assert both == pytest.approx(f[0] + link + pair, rel=1e-12)
    # Outside every o-space, and near the single person, who forms no group.
    assert fm.polyline(line(-3, 1 + r_g + 0.01, 5, 1 + r_g + 0.01))[0] == 0.0
    alone = fm.polyline(line(19, 0.5, 21, 0.5))
    assert alone[0] == 0.0 and alone[2] > 0.5


def test_group_space_takes_the_groups_from_the_scene_relations():
    persons = [{"id": 10 + k, "x": x, "y": y} for k, (x, y) in enumerate(TRIANGLE)]
    scene = scene_from_dict({
        "room": {"x_min": -5, "y_min": -5, "x_max": 5, "y_max": 5}, "persons": persons,
        "relations": [[11, 10], [12, 11]], "starts": [[-4, -4]], "goal": [4, 4]})
    fm = FeatureModel.from_scene(scene, FeatureParams(features=["group_space"]))
    assert fm.groups == ((0, 1, 2),)
    r_g = (2 * math.sqrt(2) + 2) / 3 + 0.3
    assert abs(fm.polyline(line(-3, 1.4, 5, 1.4))[0] - hinge_integral(r_g, 0.4)) \
        <= hinge_bound(r_g, 0.4)


# -- obstacle ------------------------------------------------------------------------------

def wall_map():
    """0.1 m cells over x ∈ [−10, 20], y ∈ [0, 6], occupied for y >= 5: a cell of row r
    (y ∈ [0.1 r, 0.1 r + 0.1)) below the wall has clearance (49.5 − r) × 0.1 m (its centre's
    distance to the wall); the grid's other borders are >= 3 m from the paths."""
    occupied = np.zeros((60, 300), bool)
    occupied[50:] = True
    return ObstacleMap(OccupancyGrid(occupied, (-10.0, 0.0), 0.1))


def test_obstacle_toward_a_wall():
    fm = model([(50, 50)], ["obstacle", "obstacle@0.3"], obstacles=wall_map())
    # Rows 45..48 have clearance 0.45, 0.35, 0.25, 0.15: ρ_o = 0.5 counts
    # (0.05 + 0.15 + 0.25 + 0.35) × 0.1 = 0.08 = ∫_{4.5}^{4.9} (y − 4.5) dy; ρ = 0.3: 0.02.
    up = fm.polyline(line(5, 3, 5, 4.9))
    np.testing.assert_allclose(up, [0.08, 0.02], rtol=1e-12)
    # Slanted: each row is crossed over 0.1 / sin α, exactly (no sampling error).
    slanted = fm.polyline(line(2, 3, 5, 4.9))
    sin = 1.9 / math.hypot(3, 1.9)
    np.testing.assert_allclose(slanted, [0.08 / sin, 0.02 / sin], rtol=1e-12)
    # Along the wall in row 47 (clearance 0.25) for 10 m: 0.25 × 10; obstacle@0.3: 0.05 × 10.
    along = fm.polyline(line(0, 4.75, 10, 4.75))
    np.testing.assert_allclose(along, [2.5, 0.5], rtol=1e-12)
    assert fm.polyline(line(0, 4.0, 10, 4.0)).tolist() == [0.0, 0.0]  # 0.95 m off


def test_obstacle_does_not_depend_on_the_resolution():
    office = load_scene_file(ROOT / "data" / "scenes" / "office.json")
    t = np.linspace(0, 1, 15)
    path = np.column_stack([1 + 18 * t, 7 + 5 * np.sin(11 * t)])
    f = [FeatureModel.from_scene(office, FeatureParams(features=["obstacle"], resolution=r))
         .polyline(path)[0] for r in (0.1, 0.01)]
    assert f[0] > 0.5
    assert f[0] == pytest.approx(f[1], rel=1e-12)


ROOM = Room(0.0, 0.0, 10.0, 6.0)


def test_wall_along_and_towards_the_room_border():
    fm = model([(50, 50)], ["wall", "wall@1.0", "obstacle"], room=ROOM)
    # Along the border 0.2 m off for 4 m: (ρ − 0.2) × 4, for ρ = 0.5 and 1.0; no obstacle.
    np.testing.assert_allclose(fm.polyline(line(1, 0.2, 5, 0.2)), [1.2, 3.2, 0.0], rtol=1e-12)
    # Straight at the border from 3 m off: ∫_0^ρ (ρ − c) dc = ρ²/2, within the midpoint
    # rule's error at the hinge's kink (slope 1: k²/8).
    towards = fm.polyline(line(5, 3, 5, 0))
    np.testing.assert_allclose(towards[:2], [0.125, 0.5], atol=K**2 / 8)
    # Along the middle of the room (1 m or more from every edge): nothing.
    assert fm.polyline(line(1.2, 3, 8.8, 3))[:2].tolist() == [0.0, 0.0]
    # Outside the room the path is in the wall: ρ per metre.
    np.testing.assert_allclose(fm.polyline(line(-5, -20, 15, -20))[:2], [10.0, 20.0])


def test_wall_takes_the_nearer_of_an_obstacle_and_the_border():
    # The map's wall at y = 5 (wall_map) and the room's border at y = 1: a path at y = 4.75
    # is 0.25 m from the map's wall, one at y = 1.1 0.1 m from the border (and 1.1 m from the
    # raster's edge, which `obstacle` counts as a wall).
    fm = model([(50, 50)], ["wall", "obstacle"], obstacles=wall_map(), room=Room(-10, 1, 20, 6))
    np.testing.assert_allclose(fm.polyline(line(0, 4.75, 10, 4.75)), [2.5, 2.5], rtol=1e-12)
    np.testing.assert_allclose(fm.polyline(line(0, 1.1, 10, 1.1)), [4.0, 0.0], rtol=1e-12)
    # Without a room (a model built by hand) it is `obstacle`.
    alone = model([(50, 50)], ["wall", "obstacle"], obstacles=wall_map())
    points = np.random.default_rng(0).uniform([-10, 0], [20, 6], (2000, 2))
    dens = alone.densities(points)
    assert (dens[:, 1] > 0).sum() > 100
    np.testing.assert_array_equal(dens[:, 0], dens[:, 1])


def test_obstacle_from_scene_polygons_and_zero_without_obstacles(metropolis):
    scene = scene_from_dict({
        "room": {"x_min": 0, "y_min": 0, "x_max": 10, "y_max": 10}, "persons": [],
        "obstacles": [[[4, 2], [6, 2], [6, 8], [4, 8]]], "starts": [[1, 1]], "goal": [9, 9]})
    fm = FeatureModel.from_scene(scene, FeatureParams(features=["obstacle", "length"]))
    assert fm.polyline(line(3.7, 3, 3.7, 7))[0] > 0.5  # 0.3 m from the block, 4 m long
    assert fm.polyline(line(2.5, 3, 2.5, 7))[0] == 0.0  # 1.5 m from everything
    free = FeatureModel.from_scene(metropolis, FeatureParams(features=["obstacle", "length"]))
    points = np.random.default_rng(0).random((500, 2)) * 10
    assert (free.segments(points[:-1], points[1:])[:, 0] == 0).all()
    assert (free.densities(points)[:, 0] == 0).all()


# -- crossing ------------------------------------------------------------------------------

# Two related persons 2 m apart on the x axis: the link is the segment (0, 0)-(2, 0).
LINKED = dict(persons=[[0.0, 0.0], [2.0, 0.0]], features=["crossing"], relations=[(0, 1)])


@pytest.mark.parametrize("path, count", [
    (line(1.0, -1.0, 1.0, 1.0), 1.0),  # straight through the middle
    (line(0.5, 1.0, 1.7, -3.0), 1.0),  # at a slant
    (line(2.5, -1.0, 2.5, 1.0), 0.0),  # past the link's end
    (line(-3.0, 0.5, 5.0, 0.5), 0.0),  # alongside, however close
    (line(1.0, -1.0, 1.0, 0.0), 0.5),  # ends on the link
    (line(0.0, 0.0, 2.0, 0.0), 0.0),  # along the link itself
    (np.array([[1.0, -1.0], [1.0, 1.0], [1.2, -1.0]]), 2.0),  # through and back
    (np.array([[1.0, -1.0], [1.0, 0.0], [1.3, 1.0]]), 1.0),  # through, split on the link
    (np.array([[1.0, -1.0], [1.0, 0.0], [1.3, -1.0]]), 1.0),  # touches it and turns back
])
def test_crossing_counts_the_cuts_through_a_link(path, count):
    assert model(**LINKED).polyline(path)[0] == count


SLANTED = dict(persons=[[0.0, 0.0], [2.0, 1.4]], features=["crossing"], relations=[(0, 1)])


@pytest.mark.parametrize("path, count, metric", [
    (np.array([[0.6, -1.0], [1.0, 0.7], [1.4, -1.0]]), 1.0, 0),  # touches it, turns back
    (line(1.0, -1.0, 1.0, 0.7), 0.5, 0),  # ends on the link
    (np.array([[0.6, -1.0], [1.0, 0.7], [1.4, 2.0]]), 1.0, 1),  # through, split on it
    (line(2.0, -1.0, 2.0, 2.0), 1.0, 1),  # through its end
    (np.array([[0.0, 1.0], [0.5, 0.35], [1.5, 1.05], [2.0, 2.0]]), 1.0, 0),  # along, back
    (np.array([[0.0, 1.0], [0.5, 0.35], [1.5, 1.05], [2.0, 0.0]]), 1.0, 1),  # along, over
    (line(-2.0, -1.4, 4.0, 2.8), 0.0, 0),  # along its line
])
@pytest.mark.parametrize("shift", [(0.0, 0.0), (-51.225, -51.225), (500_000.3, 5_600_000.7)])
def test_crossing_and_its_metric_decide_touches_alike_wherever_they_lie(path, count, metric,
                                                                         shift):
    """A path through a point on a slanted link, both moved by a ROS map's origin or a UTM
    offset: the rounding of the moved coordinates must not turn a touch into a cut (at
    (−51.225, −51.225) the touch and turn back counted 2, and the metric 2 crossings). The
    metric counts passes from one side to the other (it missed those at a vertex)."""
    from pipeline.core.social import relation_crossings

    shift = np.array(shift)
    fm = model(**(SLANTED | {"persons": np.array(SLANTED["persons"]) + shift}))
    assert fm.polyline(path + shift)[0] == count
    assert relation_crossings(path + shift, fm.link_a, fm.link_b) == metric


def test_crossing_does_not_depend_on_how_the_path_is_split():
    fm = model(**LINKED)
    rng = np.random.default_rng(0)
    for _ in range(50):
        a, b = rng.uniform(-1, 3, (2, 2))
        whole = fm.polyline(np.array([a, b]))[0]
        cuts = np.sort(rng.random(rng.integers(1, 6)))
        pieces = np.vstack([a, a + cuts[:, None] * (b - a), b])
        assert fm.polyline(pieces)[0] == pytest.approx(whole, abs=1e-12)
        assert whole in (0.0, 0.5, 1.0)


def test_crossing_counts_every_link_and_matches_the_crossings_metric(metropolis):
    from pipeline.core.social import relation_crossings

    fm = FeatureModel.from_scene(metropolis, FeatureParams(features=["crossing"]))
    path = wiggly(metropolis)
    count = fm.polyline(path)[0]
    assert count >= 2
    assert count == relation_crossings(path, fm.link_a, fm.link_b)
    assert np.isnan(fm.densities(path)[:, 0]).all()  # no density of position: not a costmap


# -- properties of every feature -----------------------------------------------------------

EVERY = EVERY_LOCAL + ("obstacle", "wall", "goal_deviation", "length")


@pytest.fixture(scope="module")
def office():
    return load_scene_file(ROOT / "data" / "scenes" / "office.json")


def wiggly(scene):
    x0, y0, x1, y1 = scene.room.bounds
    t = np.linspace(0, 1, 9)
    return np.column_stack([x0 + 1 + (x1 - x0 - 2) * t,
                            y0 + (y1 - y0) * (0.5 + 0.3 * np.sin(9 * t))])


@pytest.mark.parametrize("scene_name", ["metropolis", "office"])
def test_resolution_independence(scene_name, metropolis, office):
    # The midpoint error falls as k²: the straight-line bounds above at k = 0.1 are at most
    # 0.3 % of their integrals; relation's projection indicator jumps (error O(k) at a link
    # end), so it gets 1 %.
    scene = {"metropolis": metropolis, "office": office}[scene_name]
    path = wiggly(scene)
    coarse, fine = (FeatureModel.from_scene(scene, FeatureParams(features=list(EVERY),
                                                                 resolution=r)).polyline(path)
                    for r in (0.1, 0.01))
    for name, c, f in zip(EVERY, coarse, fine, strict=True):
        if name in ("obstacle", "wall") and scene_name == "metropolis":
            assert c == f == 0.0  # no obstacles, and the path keeps 1 m off the edges
            continue
        assert f > 0, name
        assert c == pytest.approx(f, rel=0.01 if name == "relation" else 3e-3), name


def test_features_add_over_a_split_segment(office):
    fm = FeatureModel.from_scene(office, FeatureParams(features=list(EVERY)))
    a, b = np.array([8.0, 6.0]), np.array([19.5, 13.5])  # past the goal (18, 12.2)
    whole = fm.segments(a, b)[0]
    assert (whole > 0).all()
    # Split where a sub-step ends: the same midpoints, the same sums.
    n_sub = math.ceil(np.linalg.norm(b - a) / K)
    m = a + (n_sub // 2) / n_sub * (b - a)
    aligned = fm.segments(np.array([a, m]), np.array([m, b])).sum(axis=0)
    np.testing.assert_allclose(aligned, whole, rtol=1e-10)
    # Anywhere else: the exact features add exactly, the sub-stepped ones within the
    # midpoint rule's error (< 0.3 % as above).
    m = a + 0.3712 * (b - a)
    split = fm.segments(np.array([a, m]), np.array([m, b])).sum(axis=0)
    exact = [EVERY.index(n) for n in ("obstacle", "goal_deviation", "length")]
    np.testing.assert_allclose(split[exact], whole[exact], rtol=1e-12)
    np.testing.assert_allclose(split, whole, rtol=3e-3)


def test_zero_far_from_everyone(metropolis):
    # A path 20 m outside the room: every person, link and group out of reach.
    fm = FeatureModel.from_scene(metropolis, FeatureParams(features=list(EVERY)))
    f = fm.polyline(line(-30, -20, 40, -20))
    assert f[:len(EVERY_LOCAL) + 1].tolist() == [0.0] * (len(EVERY_LOCAL) + 1)
    assert f[EVERY.index("wall")] == pytest.approx(0.5 * 70.0)  # outside the room: in the wall
    assert f[-1] == pytest.approx(70.0)


def test_densities_are_the_integrands_of_segments(office):
    # A segment of tiny length ℓ centred on p is one sub-step with its midpoint at p:
    # ℓ·density(p) for the sub-stepped features. The ones cut at kinks (relation, obstacle,
    # wall) agree as closely unless the segment crosses a kink or jump of the integrand: a
    # link's edge (slope 1: off by < ℓ/2) or end (a jump < ρ_r), a cell border (neighbouring
    # cells' clearances differ by <= √2 × 0.05 m).
    fm = FeatureModel.from_scene(office, FeatureParams(features=list(EVERY)))
    rng = np.random.default_rng(3)
    x0, y0, x1, y1 = office.room.bounds
    p = rng.uniform([x0, y0], [x1, y1], (4000, 2))
    u = rng.normal(size=(4000, 2))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    ell = 1e-4
    seg = fm.segments(p - 0.5 * ell * u, p + 0.5 * ell * u) / ell
    dens = fm.densities(p)
    assert np.isnan(dens[:, EVERY.index("goal_deviation")]).all()
    assert (dens[:, EVERY.index("length")] == 1.0).all()
    jump = {"relation": 0.6, "obstacle": math.sqrt(2) * 0.05, "wall": math.sqrt(2) * 0.05}
    for k, name in enumerate(EVERY):
        if name == "goal_deviation":
            continue
        assert (dens[:, k] > 0).sum() > 40, name
        close = np.abs(seg[:, k] - dens[:, k]) <= 1e-9
        if name in jump:
            assert close.mean() > 0.99, name
            assert np.abs(seg[:, k] - dens[:, k]).max() <= jump[name], name
        else:
            assert close.all(), name


def test_tiled_densities_equal_the_sums_over_everything():
    # Tiles look only at the persons, links and groups within reach (the Gaussian's
    # 7.43 σ included); what they leave out adds exactly 0, so the bits must not change.
    from pipeline.core.scenegen import RandomSceneSpec, random_scene

    scene = random_scene(RandomSceneSpec(width=30, height=30, n_groups=14, n_singles=14),
                         np.random.default_rng(0))
    fm = FeatureModel.from_scene(scene, FeatureParams(features=list(EVERY_LOCAL)))
    assert len(fm.groups) > 8 and len(np.unique(fm.headings)) > 20
    points = np.random.default_rng(1).random((20000, 2)) * 30
    tiled = fm._tiled(points, fm.selected)
    assert ((tiled > 0).sum(axis=0) > 100).all()
    np.testing.assert_array_equal(tiled, fm._evaluate(points, fm.selected))
    # a building's map round the room: the tiles nothing reaches are skipped, and are 0
    far = np.random.default_rng(2).random((40000, 2)) * 110 - 40
    tiled = fm._tiled(far, fm.selected)
    assert ((tiled > 0).sum(axis=0) > 100).all() and (tiled == 0).all(axis=1).mean() > 0.7
    np.testing.assert_array_equal(tiled, fm._evaluate(far, fm.selected))


def test_columns_follow_the_selected_order(metropolis):
    path = wiggly(metropolis)
    names = ["length", "front", "social@0.8", "relation"]
    f = FeatureModel.from_scene(metropolis, FeatureParams(features=names)).polyline(path)
    full = FeatureModel.from_scene(metropolis, FeatureParams(features=list(EVERY)))
    g = full.polyline(path)
    np.testing.assert_allclose(f, [g[EVERY.index(n)] for n in names], rtol=1e-12)


@pytest.mark.parametrize("scene_name", ["metropolis", "office"])
def test_edge_features_integrate_each_pair_once_and_agree_with_segments(scene_name, metropolis,
                                                                        office):
    # Both directions of a lattice edge cover the same points: every feature but
    # goal_deviation is the same both ways (to rounding); goal_deviation, the increase of
    # the distance to the goal, is not, and is integrated per direction.
    scene = {"metropolis": metropolis, "office": office}[scene_name]
    fm = FeatureModel.from_scene(scene, FeatureParams(features=[*EVERY, "crossing"]))
    positions, src, dst = lattice_graph(scene, 0.5, 16)
    # a one-way edge, a self-loop and a repeated edge as well
    src = np.concatenate([src, [0, 5, src[0]]])
    dst = np.concatenate([dst, [len(positions) - 1, 5, dst[0]]])
    edges = fm.edge_features(positions, src, dst)
    direct = fm.segments(positions[src], positions[dst])
    np.testing.assert_allclose(edges, direct, rtol=1e-9, atol=1e-12)
    forward = src <= dst  # integrated, not copied: the same bits
    assert np.array_equal(edges[forward], direct[forward])
    deviation = EVERY.index("goal_deviation")
    backward = fm.segments(positions[dst], positions[src])[:, deviation]
    assert (np.abs(backward - direct[:, deviation]) > 0.1).any()
    assert (edges[:, :-1] != 0).any(axis=0).sum() >= len(EVERY) - (scene_name == "metropolis")


# -- what a new feature kind needs (docs/architecture.md "Adding a feature") ---------------

def test_every_kind_is_in_the_property_tests_or_tested_apart():
    # EVERY runs each kind through the properties above (resolution, splitting, densities,
    # edges); a kind added to PARAMETER_FIELD must join it (crossing is no density: its own
    # tests; intimate is social at 0.45 m)
    kinds = {FeatureParams(features=[n]).selected()[0].kind for n in EVERY}
    assert set(FEATURE_KINDS) - {"crossing", "intimate"} == kinds


@pytest.mark.parametrize("value", [0.37, 2.5])
def test_a_model_from_the_params_takes_every_constant(metropolis, value):
    # FeatureParams' constants reach the model: a plain name (no @value) takes them there
    for name in FeatureParams().constants():
        params = dataclasses.replace(FeatureParams(), **{name: value})
        assert getattr(FeatureModel.from_scene(metropolis, params), name) == value, name
    for kind, field in PARAMETER_FIELD.items():
        if field is not None:
            params = dataclasses.replace(FeatureParams(features=[kind]), **{field: value})
            assert FeatureModel.from_scene(metropolis, params).selected[0].value == value, kind


def test_a_kind_without_a_density_is_refused_not_computed_as_another():
    fm = model([(0, 0)], ["social"])
    with pytest.raises(ValueError, match="'new_kind' has no density"):
        fm._evaluate(np.zeros((3, 2)), (Feature("new_kind", "new_kind", 1.0),))


def test_a_density_of_unknown_reach_is_evaluated_everywhere(monkeypatch):
    # _evaluate's kinds: densities and segments reach them, in batches of any size (tiles no
    # person reaches are skipped for the person kinds only: the others were 0 there)
    fm = model([(0, 0)], ["social"])
    monkeypatch.setattr(FeatureModel, "_evaluate",
                        lambda self, p, features, *rest: np.ones((len(p), len(features))))
    far = np.random.default_rng(0).random((20000, 2)) * 100 + 50  # no person within reach
    assert (fm._tiled(far, (Feature("social", "social", 1.2),)) == 0).all()
    assert (fm._tiled(far, (Feature("new_kind", "new_kind", 1.0),)) == 1).all()
    fm.__dict__["selected"] = (Feature("new_kind", "new_kind", 1.0),)  # one column, as names
    assert (fm.densities(far[:10]) == 1).all()
    a = far[:300]
    assert fm.segments(a, a + [10.0, 0.0]) == pytest.approx(10.0)  # 60 000 sub-steps at once
