"""SIMULATED, lockstep (issue #53): a hold the demo's operator leaves. The follower holds while the leader's
chain is silent; after a refused resume the virtual operator brings the leader back to the follower and the
pair resumes; the summary counts holds, the time in them and the refusals."""

from __future__ import annotations

from factr2_teleop.demo.task import DemoConfig, DemoRun
from factr2_teleop.teleop.pair import COUPLED, HOLD
from hardware.sim.faults import parse_fault

RATE_HZ = 250.0


def _run(fault: str, seconds: float = 9.0, carry_on: bool = False):
    """carry_on: the operator carries on with its task through a hold until a resume is refused (as the
    demo's operator did before it stopped for holds)."""
    cfg = DemoConfig(seconds=seconds, mode="none", clock="lockstep", rate_hz=RATE_HZ,
                     faults=(parse_fault(fault),))
    run = DemoRun(cfg)
    if carry_on:
        pause = run.operator.pause
        run.operator.pause = lambda t: pause(t) if run.pair.resume_refused else None
    phases: list[str] = []
    run.teleop.hooks.append(lambda rec: phases.append(rec.phase))
    try:
        run.run()
        return run.result(), phases
    finally:
        run.close()


def test_after_a_refused_resume_the_operator_brings_the_leader_back_and_the_pair_resumes():
    """The operator here carries on with its task through the hold: its reach takes the leader more than
    1 rad from the held follower, so the resume is refused; then it brings the leader back, the pair
    re-couples and the task goes on."""
    res, phases = _run("dxl_unplug@2.6:1.2", carry_on=True)
    assert res.refused_resumes >= 1, res.messages
    assert res.holds >= 1 and res.hold_s > 1.0
    assert any("differ too much" in m for m in res.messages)
    last_hold = max(i for i, p in enumerate(phases) if p == HOLD)
    assert last_hold < len(phases) - 2 * RATE_HZ  # left the hold with seconds of task to go
    assert phases[-1] == COUPLED and res.max_command_violation == 0


def test_the_operator_stops_its_task_during_a_hold_so_the_resume_is_not_refused():
    res, phases = _run("dxl_unplug@2.6:1.2")
    assert res.holds >= 1 and res.refused_resumes == 0, res.messages
    assert 1.0 < res.hold_s < 2.0
    assert phases[-1] == COUPLED and res.max_command_violation == 0
