"""Why the operator ended an activity in the terminal app (hardware.reasons): the controllers branch on the
kind (an emergency stop shows E-STOPPED), the screens show the message."""

from __future__ import annotations

from enum import Enum

from hardware.reasons import Reason, messages


class OperatorStop(Enum):
    STOPPED = "stopped"
    USER = "user"  # the screen's stop key (x)
    ESTOP = "emergency stop"
    APP_CLOSING = "app closing"
    ABORTED = "aborted"  # the calibration screen's abort key (x)
    TELEOP_STOPPED = "teleop stopped"  # teleop ended by its own stop


messages({
    OperatorStop.STOPPED: "stopped",
    OperatorStop.USER: "stopped by the user (x)",
    OperatorStop.ESTOP: "emergency stop",
    OperatorStop.APP_CLOSING: "app closing",
    OperatorStop.ABORTED: "aborted by the user (x)",
    OperatorStop.TELEOP_STOPPED: "teleop stopped",
})


def operator_stop(kind: OperatorStop) -> Reason:
    """The reason an operator's stop of this kind gives."""
    return Reason.of(kind)


STOPPED = operator_stop(OperatorStop.STOPPED)  # the default of a plain stop()
