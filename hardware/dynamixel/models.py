"""Dynamixel servo models used on GELLO-style leaders: model numbers, current units, torque constants.

Sources: ROBOTIS e-manual specification and control-table pages of each model (emanual.robotis.com,
docs/en/dxl/x/<model>): Model Number(0) initial value, Current Limit(38) initial value and unit, and the
stall torque / stall current pair at the recommended supply voltage. The torque constant K [N*m/A] is
stall torque / stall current at that voltage -- an output-side, datasheet-level estimate (gear losses
included, so it under-reads friction-free torque; NEXT calibration absorbs the rest). Note the XC330 series
measures current at its supply input, not in the motor phase (e-manual note under Current Limit(38)).

goal_current_units_per_nm is the scaling existing leader code bases use (GELLO/FACTR: XC330-T288 1158.73,
XM430-W210 1000/2.69); it is kept for comparison and for users porting gains, not used by the driver,
which always uses K (tau_m = K * current).
"""

from __future__ import annotations

from dataclasses import dataclass

from hardware.errors import ConfigError


@dataclass(frozen=True)
class ServoModel:
    name: str
    model_number: int
    amps_per_unit: float  # A per current unit (Present/Goal Current, Current Limit)
    current_limit_units: int  # factory Current Limit(38) [units]
    stall_torque_nm: float
    stall_current_a: float
    rated_voltage_v: float
    goal_current_units_per_nm: float | None = None  # legacy scaling of existing leaders (see module doc)

    @property
    def torque_constant(self) -> float:
        """K [N*m/A] = stall torque / stall current (output side)."""
        return self.stall_torque_nm / self.stall_current_a

    @property
    def current_limit_a(self) -> float:
        return self.current_limit_units * self.amps_per_unit

    @property
    def max_torque_nm(self) -> float:
        """Torque at the factory current limit [N*m] (K * limit)."""
        return self.torque_constant * self.current_limit_a

    @property
    def default_goal_current_units_per_nm(self) -> float:
        """Goal-current units per N*m: the legacy value where one is documented, else 1/(K*unit)."""
        if self.goal_current_units_per_nm is not None:
            return self.goal_current_units_per_nm
        return 1.0 / (self.torque_constant * self.amps_per_unit)


MODELS: dict[str, ServoModel] = {
    m.name: m
    for m in (
        # XL330: 1 mA units, 5 V rated; stall figures at 5.0 V.
        ServoModel("XL330-M288", 1200, 0.001, 1750, 0.52, 1.47, 5.0),
        ServoModel("XL330-M077", 1190, 0.001, 1750, 0.215, 1.47, 5.0),
        # XC330: 1 mA units; M288 at 5.0 V, T288 (12 V line) at 11.1 V.
        ServoModel("XC330-M288", 1240, 0.001, 2352, 0.93, 1.80, 5.0),
        ServoModel("XC330-T288", 1220, 0.001, 910, 0.92, 0.80, 11.1, goal_current_units_per_nm=1158.73),
        # XM430: 2.69 mA units, 12 V.
        ServoModel("XM430-W210", 1030, 0.00269, 1193, 3.0, 2.3, 12.0, goal_current_units_per_nm=1000 / 2.69),
        ServoModel("XM430-W350", 1020, 0.00269, 1193, 4.1, 2.3, 12.0),
    )
}
MODELS_BY_NUMBER: dict[int, ServoModel] = {m.model_number: m for m in MODELS.values()}


def get_model(name: str) -> ServoModel:
    """Look a model up by name (case-insensitive, optional '-T'/'-R' suffix)."""
    key = name.strip().upper()
    for suffix in ("-T", "-R"):
        if key.endswith(suffix) and key[:-2] in MODELS:
            key = key[:-2]
    if key not in MODELS:
        raise ConfigError(
            f"unknown Dynamixel model {name!r}",
            where="dynamixel model",
            fix=f"use one of {', '.join(MODELS)}",
        )
    return MODELS[key]


def model_name(model_number: int) -> str:
    m = MODELS_BY_NUMBER.get(int(model_number))
    return m.name if m else f"unknown model #{model_number}"


def resolve_models(model: str | list[str], n: int) -> list[ServoModel]:
    """One model per joint from a config value (one name for all, or a list of n names)."""
    if isinstance(model, str):
        return [get_model(model)] * n
    if len(model) != n:
        raise ConfigError(
            f"{len(model)} models given for {n} servos",
            where="dynamixel model",
            fix="give one model name for all servos or one per id",
        )
    return [get_model(m) for m in model]
