"""Episode seed streams: fixed values (stores and runs depend on them) and disjoint streams."""

from __future__ import annotations

from demo.seeds import MONITOR_OFFSET, dagger_seeds, episode_seed, eval_seeds


def test_seed_values_are_pinned() -> None:
    # Changing these changes every collected store and every evaluation: on purpose only.
    assert episode_seed(0, 0) == 2968811710 and episode_seed(5, 2) == 3226123765
    assert eval_seeds(0, 2) == [3652208285, 1105503284]
    assert dagger_seeds(1, 2, 2) == [3041481045, 971607590]
    assert eval_seeds(0, 1, MONITOR_OFFSET) == [1304995216]
    assert eval_seeds(3, 2, first=4) == eval_seeds(3, 6)[4:]


def test_streams_are_disjoint() -> None:
    collected = {episode_seed(s, i) for s in range(3) for i in range(2000)}
    evaluated = set(eval_seeds(0, 2000)) | set(eval_seeds(1, 2000))
    monitored = set(eval_seeds(0, 2000, MONITOR_OFFSET))
    dagger = {s for r in range(1, 4) for s in dagger_seeds(0, r, 300)}
    assert len(dagger) == 900  # rounds never repeat a start state
    for a, b in [(collected, evaluated), (collected, monitored), (collected, dagger), (evaluated, monitored),
                 (evaluated, dagger), (monitored, dagger)]:
        assert not a & b
