"""The tick's transition tables: the legal paths of both halves, and a refusal (a failed run, never a silently
wrong tick) for anything else."""

from __future__ import annotations

import pytest

from harness.channel.events import PhaseState, RunFailed, TickState
from harness.channel.state import PHASE_TRANSITIONS, TICK_TRANSITIONS, PhaseEvent, TickEvent, TickProgress


def test_a_root_tick_with_phases_goes_the_documented_way() -> None:
    s = TickProgress()
    assert s.on(TickEvent.BEGIN) is TickState.COLLECTING
    assert s.on_phase(PhaseEvent.TICK_WITH_PHASES) is PhaseState.PENDING
    assert s.on(TickEvent.HOLDER_MISSING) is TickState.AWAITING_HOLDERS
    assert s.on(TickEvent.ROUTED) is TickState.STEPPING
    assert s.on_phase(PhaseEvent.BEGIN0) is PhaseState.ZERO
    assert s.on(TickEvent.ANSWERED) is TickState.ANSWERED
    assert s.on_phase(PhaseEvent.END0) is PhaseState.ZERO_DONE
    assert s.on_phase(PhaseEvent.BEGIN1) is PhaseState.ONE
    assert s.on(TickEvent.END) is TickState.IDLE
    assert s.on(TickEvent.BEGIN) is TickState.COLLECTING  # phase 1 may still run: a new tick begins from ONE
    assert s.on_phase(PhaseEvent.TICK_WITHOUT_PHASES) is PhaseState.NONE


def test_a_child_runs_the_phases_its_parent_starts_after_its_autopilots_answered() -> None:
    s = TickProgress()
    for event in (TickEvent.BEGIN, TickEvent.ROUTED, TickEvent.ANSWERED, TickEvent.END):
        s.on(event)  # the autopilot half of the tick, over before the parent's BEGIN-TICK-0
    s.on_phase(PhaseEvent.TICK_WITHOUT_PHASES)
    assert s.on(TickEvent.BEGIN) is TickState.COLLECTING  # BEGIN-TICK-0 opens the tick again, for its phases
    s.on_phase(PhaseEvent.TICK_WITHOUT_PHASES)
    assert s.on_phase(PhaseEvent.BEGIN0) is PhaseState.ZERO
    s.on_phase(PhaseEvent.END0)
    s.on_phase(PhaseEvent.BEGIN1)
    assert s.on(TickEvent.END) is TickState.IDLE  # phase 1 over: the tick ends with no BEGIN-TICK-AC in it


@pytest.mark.parametrize(
    ("tick", "event"),
    [
        (TickState.IDLE, TickEvent.ANSWERED),
        (TickState.STEPPING, TickEvent.BEGIN),
        (TickState.STEPPING, TickEvent.END),
    ],
)
def test_an_event_the_table_does_not_list_fails_the_run(tick: TickState, event: TickEvent) -> None:
    s = TickProgress()
    s.tick = tick
    with pytest.raises(RunFailed, match="tick machine"):
        s.on(event)
    assert s.tick is tick


def test_phase_1_cannot_start_before_phase_0_is_over() -> None:
    s = TickProgress()
    s.on_phase(PhaseEvent.TICK_WITH_PHASES)
    with pytest.raises(RunFailed, match="BEGIN-TICK-1"):
        s.on_phase(PhaseEvent.BEGIN1)


def test_every_state_is_in_the_tables_and_reachable() -> None:
    for table, start in ((TICK_TRANSITIONS, TickState.IDLE), (PHASE_TRANSITIONS, PhaseState.NONE)):
        assert set(table) == set(type(start))
        seen, todo = {start}, [start]
        while todo:
            for new in table[todo.pop()].values():  # type: ignore[index]
                if new not in seen:
                    seen.add(new)
                    todo.append(new)
        assert seen == set(type(start))
