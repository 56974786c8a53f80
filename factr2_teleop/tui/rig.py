"""Rig screen: the rig's leaders, followers and cameras with live status, connect/disconnect, the doctor's
checks, and picking another rig file."""

from __future__ import annotations

import numpy as np
from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import Vertical, VerticalScroll
from textual.screen import ModalScreen
from textual.widgets import Input, OptionList, Static

from factr2_teleop.tui.base import BaseScreen
from factr2_teleop.tui.widgets import fmt

HEAD = f"{'device':<10} {'role':<8} {'link':<5} {'mode':<10} {'state':<7} {'temp':>5} {'read':>7}  errors"


def device_lines(statuses) -> list[str]:
    """Per device: name, role, link, mode, ACTIVE/SAFE, max temperature, read round trip, errors."""
    out = [HEAD]
    for d in statuses:
        link = "UP" if d.connected else "down"
        state = "-" if not d.connected else ("SAFE" if d.safe else "ACTIVE")
        temp = "-" if not np.isfinite(d.temp_max_c) else f"{d.temp_max_c:.0f}C"
        rt = "-" if not np.isfinite(d.read_ms) else f"{d.read_ms:.1f}ms"
        err = ", ".join(d.errors) if d.errors else ("none" if d.connected else "-")
        out.append(
            f"{d.name[:10]:<10} {d.role:<8} {link:<5} {d.mode[:10]:<10} {state:<7} {temp:>5} {rt:>7}  {err}"
        )
        out.append(f"{'':<10} {d.driver}/{d.arm} on {d.endpoint}"[:78])
    return out


def doctor_findings(runtime) -> list[str]:
    """The doctor's read-only checks for this rig (hardware.doctor), as lines. Blocking: call in a worker."""
    from hardware import doctor

    lines = []
    rig = runtime.rig
    ports = doctor.check_serial_ports()
    lines.append(f"INFO  serial ports: {', '.join(p.path for p in ports) or 'none found'}")
    cans = doctor.check_can_interfaces()
    lines.append(
        f"INFO  CAN interfaces: {', '.join(f'{c.name} ({c.operstate})' for c in cans) or 'none found'}"
    )
    for c in cans:
        lines += [f.line() for f in doctor.run_can_checks(c.name)]
    if runtime.connected:
        lines.append(
            "INFO  device probes skipped: the rig is connected (its drivers hold the ports) -- "
            "disconnect (c) and run the doctor again"
        )
        return lines
    twin = None
    try:  # every device through its kind's probe (hardware.doctor.rig_checks), a twin's through the twin
        if rig.simulated:
            from hardware.connect import serve_twin

            twin = serve_twin(rig)
            rig = rig.with_endpoints(twin.twin.endpoints)
            lines.append("INFO  SIMULATED rig: probing the twin's emulated devices through their protocols")
        checks, notes = doctor.rig_checks(rig)
        lines += [f"INFO  {n}" for n in notes]
        for chk in checks:
            lines.append(f"{'ERROR' if chk.failed else 'OK   '} {chk.title}")
            lines += [f"      {d}" for d in chk.details] + [f.line() for f in chk.findings]
    finally:
        if twin is not None:
            twin.stop()
    return lines


class RigPicker(ModalScreen[str | None]):
    """Pick a built-in rig or type the path of a rig file. Enter picks, Escape cancels."""

    BINDINGS = [Binding("escape", "cancel", "Cancel")]

    def __init__(self, rigs: list[str]):
        super().__init__()
        self.rigs = rigs

    def compose(self) -> ComposeResult:
        with Vertical(id="picker"):
            yield Static(
                "Pick a rig (Enter) or type a rig file path below (Enter). Escape: cancel.", markup=False
            )
            yield OptionList(*self.rigs, id="rig-list")
            yield Input(placeholder="path/to/rig.toml", id="rig-path")

    def on_option_list_option_selected(self, ev: OptionList.OptionSelected) -> None:
        self.dismiss(self.rigs[ev.option_index])

    def on_input_submitted(self, ev: Input.Submitted) -> None:
        self.dismiss(ev.value.strip() or None)

    def action_cancel(self) -> None:
        self.dismiss(None)


class RigScreen(BaseScreen):
    BINDINGS = [
        Binding("c", "toggle_connect", "Connect/Disconnect"),
        Binding("d", "doctor", "Doctor"),
        Binding("o", "open_rig", "Other rig"),
    ]

    def compose_body(self) -> ComposeResult:
        with VerticalScroll(id="body"):
            yield Static(markup=False, id="rig-head")
            yield Static(markup=False, id="devices")
            yield Static(markup=False, id="cameras")
            yield Static("doctor: press d to run the read-only checks", id="doctor", markup=False)

    def refresh_view(self) -> None:
        rt = self.app.runtime
        r = rt.rig
        clock = ""
        if rt.connected:
            clock = " | clock: " + ("lockstep (simulated time)" if rt.lockstep else "real time")
        self.query_one("#rig-head", Static).update(
            f"{rt.describe()}\nfile: {r.path}{clock}\n"
            f"keys: c {'disconnect' if rt.connected else 'connect'}, d doctor, o other rig"
        )
        self.query_one("#devices", Static).update("\n".join(device_lines(rt.statuses())))
        cams = [
            f"camera {c.name}: {c.source} {c.width}x{c.height} @{c.fps:g} fps -- configured, not streamed "
            f"by the TUI"
            for c in r.cameras
        ] or ["cameras: none configured"]
        hands = (
            ["leader hand: SIMULATED virtual hand holds the twin leader at its start pose"]
            if rt.hands
            else []
        )
        self.query_one("#cameras", Static).update("\n".join(cams + hands))

    def action_toggle_connect(self) -> None:
        rt = self.app.runtime
        if rt.connected:
            self.app.stop_activities()
            self.background(rt.disconnect, "disconnect")
        else:
            self.app.say(f"connecting to {rt.rig.name} ...")
            self.background(rt.connect, "connect")

    def action_doctor(self) -> None:
        widget = self.query_one("#doctor", Static)
        widget.update("doctor: running ...")
        self.background(
            lambda: doctor_findings(self.app.runtime),
            "doctor",
            lambda lines: widget.update("doctor:\n" + "\n".join(lines)),
        )

    def action_open_rig(self) -> None:
        def picked(name: str | None) -> None:
            if not name:
                return
            self.app.stop_activities()
            self.background(lambda: self.app.runtime.select_rig(name), "open rig")

        self.app.push_screen(RigPicker(self.app.runtime.available_rigs()), picked)


__all__ = ["RigScreen", "device_lines", "doctor_findings", "fmt"]
