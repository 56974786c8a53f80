"""Teleop screen: per-joint q and tau_ext of leader and follower, contact, loop rate and p99 period, feedback
gain and mode, recording controls (start, stop, discard, success/failure, note), episode counter and time."""

from __future__ import annotations

import time

import numpy as np
from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import Vertical
from textual.screen import ModalScreen
from textual.widgets import Input, Static

from factr2_teleop.tui.base import BaseScreen
from factr2_teleop.tui.teleop_ctl import GAIN_STEP
from factr2_teleop.tui.widgets import bar, duration, fmt

Q_RANGE = 1.6  # rad: bar span for joint positions (beyond: '<' / '>' at the end of the bar)
TAU_RANGE = 4.0  # N*m: bar span for external torques
TAU_FB_RANGE = 0.3  # N*m: bar span for the leader's feedback torque


def record_arrays(rec) -> tuple:
    """(leader q, follower q, tau_ext, leader feedback torque) of a TickRecord (feedback: the command when
    the law did not run)."""
    fb = rec.tau_feedback if rec.tau_feedback is not None else rec.leader_tau_cmd
    return rec.leader.q, rec.follower.q, rec.tau_ext, fb


def joint_lines(lq=(), fq=(), te=(), fb=()) -> list[str]:
    """Per joint: leader q, follower q, follower tau_ext, leader feedback torque (bars + numbers)."""
    lq, fq, te, fb = (np.asarray(a if a is not None else [], float) for a in (lq, fq, te, fb))
    n = max(len(fq), len(lq))
    out = [
        f"{'j':<2} {'leader q [rad]':<18} {'follower q [rad]':<18} {'F tau_ext [N*m]':<18} "
        f"{'L tau_fb [N*m]':<18}"
    ]

    def cell(a, j, rng, prec=2):
        v = a[j] if j < len(a) else float("nan")
        return f"{bar(v, -rng, rng, 11)}{fmt(v, 7, prec)}"

    for j in range(n):
        out.append(
            f"{j + 1:<2} {cell(lq, j, Q_RANGE)} {cell(fq, j, Q_RANGE)} {cell(te, j, TAU_RANGE)} "
            f"{cell(fb, j, TAU_FB_RANGE)}"
        )
    return out


def _num(x: float, prec: int) -> str:
    return "-" if x is None or not np.isfinite(x) else f"{x:.{prec}f}"


class NoteDialog(ModalScreen[str | None]):
    """A one-line note for the recording. Enter saves, Escape cancels. (Space types a space here; the
    emergency stop in this dialog is ctrl+space.)"""

    BINDINGS = [Binding("escape", "cancel", "Cancel")]

    def compose(self) -> ComposeResult:
        with Vertical(id="picker"):
            yield Static(
                "Note for the recording (Enter: save, Escape: cancel). E-STOP here: ctrl+space", markup=False
            )
            yield Input(placeholder="what happened", id="note")

    def on_input_submitted(self, ev: Input.Submitted) -> None:
        self.dismiss(ev.value.strip() or None)

    def action_cancel(self) -> None:
        self.dismiss(None)


class TeleopScreen(BaseScreen):
    BINDINGS = [
        Binding("t", "toggle", "Teleop"),
        Binding("m", "mode", "Mode"),
        Binding("plus,equals_sign", "gain(1)", "K+"),
        Binding("minus", "gain(-1)", "K-"),
        Binding("r", "rec_start", "Rec"),
        Binding("x", "rec_stop", "Stop"),
        Binding("d", "rec_discard", "Discard"),
        Binding("s", "mark('success')", "Ok"),
        Binding("f", "mark('failure')", "Fail"),
        Binding("n", "note", "Note"),
        Binding("v", "operator", "Sim operator", show=False),
        Binding("p", "push", "Sim push", show=False),
        Binding("h", "match", "Sim match", show=False),
    ]

    def compose_body(self) -> ComposeResult:
        with Vertical(id="body"):
            yield Static(markup=False, id="tele-head")
            yield Static(markup=False, id="joints")
            yield Static(markup=False, id="rec")
        self._wall = (time.monotonic(), 0)
        self._wall_rate = float("nan")

    def refresh_view(self) -> None:
        tc = self.app.teleop
        rt = self.app.runtime
        snap = tc.snapshot()
        rec = None
        phase, timing_line, contact = "stopped", "loop: not running", "-"
        if snap is not None:
            rec = next(iter(snap.records.values()), None)
            phase = ", ".join(snap.phases.values()) or "-"
            tm = snap.timing
            now = time.monotonic()
            t_prev, n_prev = self._wall
            if now - t_prev > 1.0:
                self._wall_rate = (tm.ticks - n_prev) / (now - t_prev)
                self._wall = (now, tm.ticks)
            clock = "sim clock" if rt.lockstep else "wall clock"
            wall = (
                f", {self._wall_rate:.0f} ticks/s wall"
                if rt.lockstep and np.isfinite(self._wall_rate)
                else ""
            )
            timing_line = (
                f"loop {_num(tm.rate_hz, 0)} Hz ({clock}), p99 period {_num(tm.period_p99_ms, 2)} ms, "
                f"{tm.overruns} overruns{wall}"
            )
            contact = "CONTACT" if rec is not None and rec.contact else "free"
            if snap.error:
                timing_line += f" | STOPPED BY {snap.error}"
        run = "RUNNING" if tc.running else "STOPPED"
        sim = ""
        if rt.simulated:
            sim = " | sim: operator " + ("ON" if tc.operator else "off") + " (v), push (p), match leader (h)"
        gate = rec.gate if rec is not None else float("nan")
        head = (
            f"teleop {run} | phase {phase} | feedback {tc.mode} K_f {tc.gain:.2f} gate {fmt(gate, 4, 2)} | "
            f"contact: {contact}\n{timing_line}{sim}"
        )
        if tc.mode == "next" and tc.running and tc.next_flags:
            head += "\nNEXT: " + ", ".join(f"{k} {v}" for k, v in tc.next_flags.items())
        if tc.last_error:
            head += f"\nlast stop: {tc.last_error}"
        self.query_one("#tele-head", Static).update(head)
        arrays = record_arrays(rec) if rec is not None else None
        if not tc.running and rt.connected:  # stopped: the monitor's live positions, torques unknown
            st = {d.role: d.q for d in rt.statuses() if d.q is not None}
            arrays = (st.get("leader"), st.get("follower")) if st else None
        none = "no data: connect on the Rig screen, then t starts teleop"
        self.query_one("#joints", Static).update("\n".join(joint_lines(*arrays)) if arrays else none)
        rs = tc.rec_state()
        state = f"REC * episode {rs.episode} {duration(rs.duration_s)}" if rs.recording else "rec: idle"
        err = f" | RECORDER ERROR: {rs.error}" if rs.error else ""
        drop = f" | dropped {rs.dropped}" if rs.dropped else ""
        self.query_one("#rec", Static).update(
            f"{state} | episodes done {rs.episodes_done} | last: {rs.last_outcome}{drop}{err}\n"
            f"file: {rs.file or '(opens on the first r)'}"
        )

    # -- actions (blocking ones run in workers) -----------------------------------------------------------
    def action_toggle(self) -> None:
        tc = self.app.teleop
        if tc.running:
            self.background(tc.stop, "teleop stop")
        else:
            self.background(tc.start, "teleop start")

    def action_mode(self) -> None:
        try:
            self.app.say(f"feedback mode: {self.app.teleop.cycle_mode()}")
        except Exception as e:  # noqa: BLE001
            self.app.say(str(e))

    def action_gain(self, sign: int) -> None:
        tc = self.app.teleop
        self.app.say(f"feedback gain K_f = {tc.set_gain(tc.gain + sign * GAIN_STEP):.2f}")

    def _do(self, fn, label: str) -> None:
        try:
            fn()
        except Exception as e:  # noqa: BLE001 -- one line, the UI keeps running
            self.app.say(f"{label}: {e}")

    def action_rec_start(self) -> None:
        self._do(self.app.teleop.rec_start, "record")

    def action_rec_stop(self) -> None:
        self._do(self.app.teleop.rec_stop, "stop recording")

    def action_rec_discard(self) -> None:
        self._do(self.app.teleop.rec_discard, "discard")

    def action_mark(self, outcome: str) -> None:
        self._do(lambda: self.app.teleop.mark(outcome), outcome)

    def action_note(self) -> None:
        def done(text: str | None) -> None:
            if text:
                self._do(lambda: self.app.teleop.note(text), "note")

        self.app.push_screen(NoteDialog(), done)

    def action_operator(self) -> None:
        tc = self.app.teleop
        if not self.app.runtime.simulated:
            self.app.say("the virtual operator exists only on simulated rigs")
            return
        tc.operator = not tc.operator
        self.app.say(
            f"SIMULATED virtual operator {'ON' if tc.operator else 'off'} (takes effect at the next start)"
        )

    def action_match(self) -> None:
        """SIMULATED: the virtual hand brings each twin leader to its follower's pose (what an operator does
        by hand before starting); only while teleop is stopped."""
        rt, tc = self.app.runtime, self.app.teleop
        s = rt.session
        if s is None or s.twin is None or tc.running:
            self.app.say("match: only on a connected simulated rig with teleop stopped")
            return
        for lname, fname in s.rig.pairs:
            if lname in rt.hands:
                q = s.followers[fname].last_state.q
                n = min(len(q), rt.hands[lname].q_ref.size)
                rt.hands[lname].q_ref[:n] = np.where(np.isfinite(q[:n]), q[:n], rt.hands[lname].q_ref[:n])
        self.app.say("SIMULATED hand moves the leader to the follower's pose (give it a few seconds)")

    def action_push(self) -> None:
        rt = self.app.runtime
        s = rt.session
        if s is None or s.twin is None:
            self.app.say("push: only on a connected simulated rig")
            return
        f = rt.rig.followers[0]
        link = last_link(f.arm)
        s.twin.push(link, [0.0, 0.0, -15.0], 2.0, f.name)
        self.app.say(f"SIMULATED push: 15 N down on {link} for 2 s")


def last_link(arm_name: str) -> str:
    """The body that carries an arm's last joint (where a simulated push is applied)."""
    import mujoco

    from hardware.arms import load_arm

    arm = load_arm(arm_name)
    m = arm.mujoco_model() if callable(arm.mujoco_model) else arm.mujoco_model
    jid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, arm.joint_names[-1])
    return m.body(m.jnt_bodyid[jid]).name
