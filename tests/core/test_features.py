"""Reward features (DESIGN §4) against hand-computed values and resolution independence."""

import numpy as np
import pytest

from pipeline.core.features import FEATURE_NAMES, Feature, FeatureModel, FeatureParams

REL, SOC, DEV, LEN = (FEATURE_NAMES.index(n) for n in FEATURE_NAMES)


def model(persons, links=(), goal=(100.0, 0.0), resolution=0.05):
    persons = np.array(persons, float).reshape(-1, 2)
    a = np.array([persons[i] for i, _ in links]).reshape(-1, 2)
    b = np.array([persons[j] for _, j in links]).reshape(-1, 2)
    return FeatureModel(a, b, persons, np.array(goal, float), 0.6, 1.2, resolution)


def test_feature_names_follow_design():
    assert FEATURE_NAMES == ("relation", "social", "goal_deviation", "length")


def test_crossing_a_link_at_right_angles():
    # Link from (0,0) to (4,0); path from (2,-2) straight up to (2,2) crosses its middle.
    # relation = ∫ max(0, 0.6 − |y|) dy = 0.6² = 0.36; persons are 2 m from the crossing, so
    # with ρ_p = 1.2 only the parts of the path within 1.2 m of a person count.
    fm = model([(0, 0), (4, 0)], links=[(0, 1)])
    f = fm.polyline(np.array([[2.0, -2.0], [2.0, 2.0]]))
    assert f[REL] == pytest.approx(0.36, rel=1e-3)
    assert f[SOC] == pytest.approx(0.0, abs=1e-12)  # nearest person at 2 m > 1.2 m
    assert f[LEN] == pytest.approx(4.0)


def test_path_outside_link_span_does_not_count():
    # Path crosses the link's line beyond its end: the projection falls outside the link.
    fm = model([(0, 0), (4, 0)], links=[(0, 1)])
    f = fm.polyline(np.array([[6.0, -2.0], [6.0, 2.0]]))
    assert f[REL] == 0.0


def test_passing_a_person_at_known_distance():
    # Straight line y = 0.5 past a person at the origin: social = ∫ max(0, 1.2 − √(x²+0.25)) dx,
    # whose closed form is below (integrate over |x| ≤ a with a = √(1.2² − 0.5²)).
    fm = model([(0, 0)])
    f = fm.polyline(np.array([[-3.0, 0.5], [3.0, 0.5]]))
    d, rho = 0.5, 1.2
    a = np.sqrt(rho**2 - d**2)
    exact = 2 * (rho * a - 0.5 * (a * np.sqrt(a**2 + d**2) + d**2 * np.arcsinh(a / d)))
    assert f[SOC] == pytest.approx(exact, rel=1e-3)
    assert f[REL] == 0.0


def test_goal_deviation_counts_only_moving_away():
    fm = model([(50, 50)], goal=(0.0, 0.0))
    # Toward the goal from (5,0) to (1,0): no deviation; then away to (4,0): 3 m.
    f = fm.polyline(np.array([[5.0, 0.0], [1.0, 0.0], [4.0, 0.0]]))
    assert f[DEV] == pytest.approx(3.0)
    # Passing the goal: from (−2,0) to (3,0) the distance falls to 0 then rises to 3.
    assert fm.polyline(np.array([[-2.0, 0.0], [3.0, 0.0]]))[DEV] == pytest.approx(3.0)


@pytest.mark.parametrize("name", ["relation", "social", "goal_deviation", "length"])
def test_resolution_independence(metropolis, name):
    # A wiggly path through the metropolis group; 0.1 m and 0.01 m sampling agree within 1 %.
    t = np.linspace(0, 1, 7)
    path = np.column_stack([1.0 + 8.0 * t, 2.0 + 5.0 * t + 1.5 * np.sin(9 * t)])
    coarse = FeatureModel.from_scene(metropolis, FeatureParams(resolution=0.1)).polyline(path)
    fine = FeatureModel.from_scene(metropolis, FeatureParams(resolution=0.01)).polyline(path)
    k = FEATURE_NAMES.index(name)
    assert fine[k] > 0
    assert coarse[k] == pytest.approx(fine[k], rel=0.01)


def test_features_add_over_concatenation(metropolis):
    fm = FeatureModel.from_scene(metropolis)
    path = np.array([[0.5, 0.5], [3.0, 4.0], [5.5, 5.5], [5.5, 9.0]])
    whole = fm.polyline(path)
    parts = fm.polyline(path[:2]) + fm.polyline(path[1:3]) + fm.polyline(path[2:])
    np.testing.assert_allclose(whole, parts, rtol=1e-12)
    np.testing.assert_allclose(fm.polylines([path[:2], path[1:]]).sum(0), whole, rtol=1e-12)


def test_segments_by_runs_give_each_polyline_its_own_bits(metropolis, monkeypatch):
    # Polylines laid end to end in one call (`runs`) are integrated in chunks of their own:
    # a segment cut by a chunk's end sums its parts chunk by chunk, so each polyline's bits
    # are those of a call of its own, however the chunks fall (a few sub-steps each here).
    import pipeline.core.features as features

    monkeypatch.setattr(features, "_CHUNK_POINTS", 7)
    fm = FeatureModel.from_scene(metropolis)
    rng = np.random.default_rng(3)
    polylines = [np.cumsum(rng.normal(0, 0.4, (n, 2)), axis=0) + [5.0, 5.0]
                 for n in (2, 9, 1, 30, 4, 3, 17)]
    a = np.concatenate([p[:-1] for p in polylines])
    b = np.concatenate([p[1:] for p in polylines])
    alone = np.concatenate([fm.segments(p[:-1], p[1:]) for p in polylines])
    together = fm.segments(a, b, [len(p) - 1 for p in polylines])
    np.testing.assert_array_equal(together, alone)


def test_segments_by_runs_give_each_polyline_its_own_relation_bits(metropolis):
    # `relation` takes each segment's link coordinates by a matrix product, whose bits
    # depend on its number of rows: polylines laid end to end get the products of their
    # own (a product of all the segments at once differed in the last bits)
    fm = FeatureModel.from_scene(metropolis)
    ends = np.concatenate(metropolis.links)
    for seed in (0, 6, 9):  # (3, 1 and 2 values of 80 walks' differed with OpenBLAS 0.3.31)
        rng = np.random.default_rng(seed)
        polylines = [ends[rng.integers(len(ends))] + np.cumsum(rng.normal(0, 0.3, (n, 2)), 0)
                     for n in rng.integers(2, 60, 80)]
        a = np.concatenate([p[:-1] for p in polylines])
        b = np.concatenate([p[1:] for p in polylines])
        alone = np.concatenate([fm.segments(p[:-1], p[1:]) for p in polylines])
        together = fm.segments(a, b, [len(p) - 1 for p in polylines])
        assert together.tobytes() == alone.tobytes()


def test_invalid_parameters():
    with pytest.raises(ValueError, match="resolution"):
        model([(0, 0)], resolution=0.0)


def test_tiled_densities_equal_the_sums_over_every_link_and_person():
    # The roadmap of a large room evaluates densities tile by tile with only the links and
    # persons near each tile; they vanish beyond ρ_r and ρ_p, so the bits must not change.
    from pipeline.core.scenegen import RandomSceneSpec, random_scene

    scene = random_scene(RandomSceneSpec(width=20, height=20, n_groups=12, n_singles=12),
                         np.random.default_rng(0))
    fm = FeatureModel.from_scene(scene)
    points = np.random.default_rng(1).random((20000, 2)) * 20
    relation, social = fm._tiled(points, (Feature("relation", "relation", fm.rho_relation),
                                          Feature("social", "social", fm.rho_personal))).T
    assert len(scene.relations) > 8 and (relation > 0).sum() > 100 and (social > 0).sum() > 100
    np.testing.assert_array_equal(relation, fm.relation_density(points))
    np.testing.assert_array_equal(social, fm.social_density(points))


def test_no_polylines_and_no_edges_give_empty_feature_tables(metropolis):
    """An empty batch is a (0, d) table, as a batch of one is a (1, d) one: a graph with no
    edges yet, or a scene without demonstrations, asks for none."""
    model = FeatureModel.from_scene(metropolis, FeatureParams())
    assert model.polylines([]).shape == (0, len(FEATURE_NAMES))
    positions = np.array([[0.5, 0.5], [5.5, 9.0]])
    none = np.zeros(0, dtype=np.int64)
    assert model.edge_features(positions, none, none).shape == (0, len(FEATURE_NAMES))
    # and one edge each way is the edge's own features both ways but goal_deviation
    both = model.edge_features(positions, np.array([0, 1]), np.array([1, 0]))
    np.testing.assert_array_equal(both[0], model.segments(positions[:1], positions[1:])[0])
    assert both[0, FEATURE_NAMES.index("goal_deviation")] == 0.0  # straight at the goal
    assert both[1, FEATURE_NAMES.index("goal_deviation")] == pytest.approx(
        float(np.linalg.norm(positions[1] - positions[0])))  # straight away from it


def test_link_batches_are_each_polylines_own_chunks_as_many_whole_as_fit():
    """`_link_batches` by hand: each polyline cut in chunks of `chunk` segments from its
    own first; consecutive chunks share a batch while the batch spans at most `chunk`
    segments (exactly `chunk` fits); a batch of one chunk is a product of its own (None)."""
    from pipeline.core.features import _link_batches
    assert _link_batches(10, 4, None) == [(slice(0, 4), None), (slice(4, 8), None),
                                          (slice(8, 12), None)]
    assert _link_batches(4, 4, [2, 2]) == [(slice(0, 4), [slice(0, 2), slice(2, 4)])]
    assert _link_batches(5, 4, [2, 3]) == [(slice(0, 2), None), (slice(2, 5), None)]
    # 6 = 4 + 2: its second chunk and the next polyline's 1 and 1 fit in one batch
    assert _link_batches(11, 4, [6, 1, 1, 3]) == [
        (slice(0, 4), None), (slice(4, 8), [slice(4, 6), slice(6, 7), slice(7, 8)]),
        (slice(8, 11), None)]
    rng = np.random.default_rng(1)
    for _ in range(200):
        runs = rng.integers(0, 9, rng.integers(1, 8)).tolist()
        chunk = int(rng.integers(1, 6))
        batches = _link_batches(sum(runs), chunk, runs)
        pieces = [p for sl, group in batches for p in (group or [sl])]
        begins = np.cumsum(runs) - runs
        assert pieces == [slice(b + lo, b + min(lo + chunk, n))
                          for b, n in zip(begins.tolist(), runs, strict=True)
                          for lo in range(0, n, chunk)]
        for k, (sl, _) in enumerate(batches):
            assert sl.stop - sl.start <= chunk
            if k + 1 < len(batches):  # the next batch's first chunk would not fit
                nxt = batches[k + 1][1][0] if batches[k + 1][1] else batches[k + 1][0]
                assert nxt.stop - sl.start > chunk
