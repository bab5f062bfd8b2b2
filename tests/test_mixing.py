import pytest
from hypothesis import given
from hypothesis import strategies as st

from lead_s2r.data.mixing import LEAD_SIM2REAL_ANCHORS, MixingSchedule, largest_remainder


def test_lead_table_is_reproduced_exactly_on_one_and_four_gpus():
    schedule = MixingSchedule.lead_sim2real("carla", "navsim")
    for epoch, (sim, real) in LEAD_SIM2REAL_ANCHORS.items():
        assert schedule.batch_sizes(epoch) == {"carla": sim, "navsim": real}
        assert schedule.batch_sizes(epoch, world_size=4) == {"carla": sim // 4, "navsim": real // 4}


def test_compositions_hold_between_anchors_and_end_real_only():
    schedule = MixingSchedule.lead_sim2real("carla", "wod")
    assert schedule.batch_sizes(2) == schedule.batch_sizes(1) == {"carla": 32, "wod": 32}
    assert schedule.batch_sizes(30) == {"carla": 8, "wod": 56}
    assert schedule.batch_sizes(60) == {"carla": 0, "wod": 64}
    assert [s for s, n in schedule.batch_sizes(31).items() if n] == ["wod"]
    sims = [schedule.batch_sizes(epoch)["carla"] for epoch in range(40)]
    assert sims == sorted(sims, reverse=True)


def test_other_batch_and_world_sizes_keep_the_global_batch():
    schedule = MixingSchedule.lead_sim2real("carla", "navsim", global_batch_size=48)
    sizes = schedule.batch_sizes(0, world_size=3)  # 16 per rank, 62.5% sim
    assert sum(sizes.values()) == 16 and sizes == {"carla": 10, "navsim": 6}
    with pytest.raises(ValueError, match="divisible"):
        schedule.batch_sizes(0, world_size=5)


def test_linear_mode_blends_between_anchors():
    schedule = MixingSchedule({0: {"a": 1, "b": 0}, 10: {"a": 0, "b": 1}}, global_batch_size=10, mode="linear")
    assert schedule.batch_sizes(0) == {"a": 10, "b": 0}
    assert schedule.batch_sizes(5) == {"a": 5, "b": 5}
    assert schedule.batch_sizes(12) == {"a": 0, "b": 10}


def test_bad_tables_are_refused():
    with pytest.raises(ValueError, match="epoch 0"):
        MixingSchedule({1: {"a": 1}})
    with pytest.raises(ValueError, match="every anchor must list"):
        MixingSchedule({0: {"a": 1, "b": 1}, 3: {"a": 1}})
    with pytest.raises(ValueError, match="positive sum"):
        MixingSchedule({0: {"a": 0, "b": 0}})


@given(
    st.lists(st.floats(0, 100), min_size=1, max_size=5).filter(lambda w: sum(w) > 1e-3),
    st.integers(1, 8),
    st.integers(1, 64),
)
def test_per_rank_sizes_are_exact_and_fair(weights, world_size, per_rank):
    names = [f"s{i}" for i in range(len(weights))]
    schedule = MixingSchedule.constant(dict(zip(names, weights, strict=True)), global_batch_size=per_rank * world_size)
    sizes = schedule.batch_sizes(0, world_size)
    assert sum(sizes.values()) == per_rank
    total = sum(weights)
    for name, weight in zip(names, weights, strict=True):
        assert abs(sizes[name] - per_rank * weight / total) < 1 + 1e-9


def test_largest_remainder_breaks_ties_by_order():
    assert largest_remainder({"a": 1, "b": 1, "c": 1}, 4) == {"a": 2, "b": 1, "c": 1}
