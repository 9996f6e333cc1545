"""System description: the JSON a user writes to get a twin of their plant.

A plant is ``cabinets.count`` CDU-cabinet pairs (the LC-Opt "cabinet"), each with
``cabinets.branches`` valve-controlled branches, each branch feeding
``cabinets.blade_groups_per_branch`` blade groups in parallel; a hot-water (HTW)
loop; ``towers.count`` cooling towers of ``towers.cells`` cells, one plate heat
exchanger train per tower; an optional heat-recovery unit.

Every number is SI (K, W, kg/s, Pa, m^3, J/K). Defaults come from
../shared/reference/frontier-cooling-physics.md (see docs/twin.md for the table).
"""

from __future__ import annotations

import difflib
import hashlib
import json
from importlib import resources
from pathlib import Path

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

SCHEMA_VERSION = 1
PSI_TO_PA = 6894.757
_REFERENCE_PACKAGE = "lcmesh.twin.systems"


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class PidGains(_Strict):
    """PID gains on a normalized error (see docs/twin.md, CDU inner loops)."""

    k: float = Field(gt=0)
    ti_s: float = Field(gt=0)
    td_s: float = Field(ge=0, default=0.0)


class PumpCurve(_Strict):
    """Head-flow curve at nominal speed, fitted as head = a - b*q^2 by the builder."""

    head_m: tuple[float, ...]
    flow_m3_s: tuple[float, ...]
    efficiency: float = Field(gt=0, le=1)
    n_parallel: int = Field(ge=1, default=1)
    speed_min: float = Field(ge=0, le=1)
    speed_max: float = Field(gt=0, le=1.5)

    @model_validator(mode="after")
    def _curve_shape(self) -> "PumpCurve":
        if len(self.head_m) != len(self.flow_m3_s) or len(self.head_m) < 2:
            raise ValueError("`head_m` and `flow_m3_s` must have the same length >= 2")
        if self.speed_min >= self.speed_max:
            raise ValueError(f"`speed_min` ({self.speed_min}) must be < `speed_max` ({self.speed_max})")
        return self


class BladeGroupParams(_Strict):
    """Thermal parameters of one branch; split evenly over its blade groups."""

    branch_heat_capacity_j_per_k: float = Field(gt=0, default=1.5e6)
    branch_conductance_w_per_k: float = Field(gt=0, default=85e3)
    conductance_flow_exponent: float = Field(ge=0, le=1.5, default=0.8)
    nominal_branch_flow_kg_s: float = Field(gt=0, default=5.67)
    heat_nonlinearity: float = Field(ge=0, default=0.015)
    heat_unit_w: float = Field(
        gt=0, default=216.7e3, description="per branch; the paper's per-unit load (a third of a 650 kW CDU)"
    )
    throttle_start_k: float = Field(default=358.15, description="blades start throttling their power (85 C)")
    shutdown_k: float = Field(default=378.15, description="throttled to zero: thermal shutdown (105 C)")

    @model_validator(mode="after")
    def _throttle(self) -> "BladeGroupParams":
        if self.shutdown_k <= self.throttle_start_k:
            raise ValueError(f"`shutdown_k` ({self.shutdown_k}) must be > `throttle_start_k` ({self.throttle_start_k})")
        return self


class CduParams(_Strict):
    hx_ua_sat_w_per_k: float = Field(gt=0, default=250e3)
    hx_ua_correction: float = Field(gt=0, default=1.6)
    hx_flow_sat_m3_s: float = Field(gt=0, default=0.0227)
    hx_secondary_volume_m3: float = Field(gt=0, default=0.255)
    r_hx_secondary_pa_per_kg_s: float = Field(gt=0, default=1_800)
    r_cabinet_pa_per_kg_s: float = Field(gt=0, default=4_700)
    primary_flow_max_kg_s: float = Field(gt=0, default=45.0)
    valve_opening_min: float = Field(ge=0, lt=1, default=0.05)
    pump: PumpCurve = PumpCurve(
        head_m=(0.0, 38.5, 53.2, 62.4, 66.1, 68.0),
        flow_m3_s=(0.0573, 0.040, 0.030, 0.020, 0.008, 0.0),
        efficiency=0.85,
        n_parallel=2,
        speed_min=0.52,
        speed_max=1.0,
    )
    dp_pid: PidGains = PidGains(k=0.1, ti_s=100.0, td_s=0.0)
    temp_pid: PidGains = PidGains(k=0.9, ti_s=35.0, td_s=9.0)
    temp_deadband_k: float = Field(ge=0, default=0.3)
    supply_temp_setpoint_k: float = Field(ge=273.15, le=330, default=301.15)
    dp_setpoint_pa: float = Field(gt=0, default=27.5 * PSI_TO_PA)
    pump_time_constant_s: float = Field(gt=0, default=5.0, description="speed ramp of the pump drive")
    valve_time_constant_s: float = Field(gt=0, default=10.0, description="stroke lag of the primary valve")


class CabinetGroup(_Strict):
    count: int = Field(ge=1, le=1000, description="C: CDU-cabinet pairs")
    branches: int = Field(ge=1, le=64, description="B: valve-controlled blade-group branches per cabinet")
    blade_groups_per_branch: int = Field(ge=1, le=10_000, default=1)
    design_heat_w: float = Field(
        gt=0, default=650e3, description="mean IT load of a cabinet; traces are scaled to it (650 kW: unscaled)"
    )
    coolant_volume_m3: float = Field(gt=0, default=0.083)
    blade_group: BladeGroupParams = BladeGroupParams()
    cdu: CduParams = CduParams()


class CellParams(_Strict):
    water_flow_kg_s: float = Field(gt=0, default=50.0)
    fan_power_nominal_w: float = Field(gt=0, default=37.3e3)
    design_heat_w: float = Field(gt=0, default=1.338e6, description="heat per cell at adj = 1")
    free_convection_air_ratio: float = Field(ge=0, lt=1, default=0.1)
    york_wet_bulb_max_f: float = Field(default=70.0, description="clamp of the fit's wet-bulb argument")
    approach_min_k: float = Field(ge=0, default=0.3)
    fan_pi: PidGains = PidGains(k=1.0, ti_s=60.0)
    fan_time_constant_s: float = Field(gt=0, default=20.0, description="speed ramp of the fan drive")
    pump_head_m: float = Field(gt=0, default=17.1)
    pump_efficiency: float = Field(gt=0, le=1, default=0.612)


class TowerGroup(_Strict):
    count: int = Field(ge=1, le=100, description="N: cooling towers")
    cells: int = Field(ge=1, le=32, description="m: cells per tower")
    cell: CellParams = CellParams()
    ehx_ua_w_per_k: float = Field(gt=0, default=4.04e6, description="plate HX, one train per tower")
    basin_volume_m3: float = Field(gt=0, default=50.0)
    stage_up_speed: float = Field(gt=0, le=1, default=0.3)
    stage_down_speed: float = Field(
        ge=0, lt=1, default=0.0, description="0: cells once on stay on (their water keeps flowing; docs/twin.md)"
    )
    stage_delay_s: float = Field(ge=0, default=300.0)
    lw_setpoint_k: float = Field(default=298.15, description="initial leaving-water setpoint")

    @model_validator(mode="after")
    def _staging(self) -> "TowerGroup":
        if self.stage_down_speed >= self.stage_up_speed:
            raise ValueError(
                f"`stage_down_speed` ({self.stage_down_speed}) must be < `stage_up_speed` ({self.stage_up_speed})"
            )
        return self


class HtwLoop(_Strict):
    supply_volume_m3: float = Field(gt=0, default=100.0)
    return_volume_m3: float = Field(gt=0, default=125.0)
    bypass_fraction: float = Field(ge=0, le=2, default=0.1)
    flow_min_kg_s: float = Field(ge=0, default=10.0)
    r_header_pa_per_kg_s: float = Field(ge=0, default=2_000 / 25)
    cdu_branch_dp_pa: float = Field(ge=0, default=50e3)
    pump: PumpCurve = PumpCurve(
        head_m=(72.0, 37.8),
        flow_m3_s=(0.003, 0.477),
        efficiency=0.835,
        n_parallel=4,
        speed_min=0.3,
        speed_max=1.2,
    )


class HeatRecovery(_Strict):
    """A heat exchanger on the HTW return feeding a district loop."""

    ua_w_per_k: float = Field(gt=0, default=150e3)
    district_flow_kg_s: float = Field(gt=0, default=20.0)
    district_supply_temp_k: float = Field(default=293.15)


class SystemDescription(_Strict):
    schema_version: int = SCHEMA_VERSION
    name: str = Field(pattern=r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,63}$")
    description: str = ""
    step_s: float = Field(gt=0, le=3600, default=15.0)
    substeps: int = Field(ge=1, le=1000, default=15, description="explicit fluid sub-steps per step")
    cabinets: CabinetGroup
    towers: TowerGroup
    htw: HtwLoop = HtwLoop()
    heat_recovery: HeatRecovery | None = None
    load_skew_seed: int = Field(ge=0, default=0, description="seed of the static within-branch load skew")

    @model_validator(mode="after")
    def _check(self) -> "SystemDescription":
        if self.schema_version != SCHEMA_VERSION:
            raise ValueError(f"`schema_version` must be {SCHEMA_VERSION}, got {self.schema_version}")
        if self.n_blade_groups > 200_000:
            raise ValueError(f"the system has {self.n_blade_groups} blade groups; at most 200000 are supported")
        sub_dt = self.step_s / self.substeps
        cab = self.cabinets
        worst_flow = 60.0  # kg/s: above any flow the CDU pump reaches
        residence = 1000.0 * min(cab.coolant_volume_m3, cab.cdu.hx_secondary_volume_m3) / worst_flow
        if sub_dt >= residence:
            raise ValueError(
                f"`substeps` = {self.substeps} gives {sub_dt:.2f} s sub-steps, not below the "
                f"{residence:.2f} s residence time of the smallest coolant volume; raise `substeps`"
            )
        return self

    @property
    def n_cabinets(self) -> int:
        return self.cabinets.count

    @property
    def n_branches(self) -> int:
        return self.cabinets.count * self.cabinets.branches

    @property
    def n_blade_groups(self) -> int:
        return self.n_branches * self.cabinets.blade_groups_per_branch

    @property
    def n_towers(self) -> int:
        return self.towers.count

    @property
    def n_cells(self) -> int:
        return self.towers.count * self.towers.cells

    def content_hash(self) -> str:
        """Stable hash of every field (the FMU cache key includes it)."""
        canonical = json.dumps(self.model_dump(mode="json"), sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(canonical.encode()).hexdigest()


class SystemDescriptionError(ValueError):
    """A system description that cannot be loaded; the message names the field."""


def reference_systems() -> list[str]:
    """Names of the shipped reference systems."""
    files = resources.files(_REFERENCE_PACKAGE).iterdir()
    return sorted(f.name.removesuffix(".json") for f in files if f.name.endswith(".json"))


def load_system(name_or_path: str | Path) -> SystemDescription:
    """Load a reference system by name (``lcopt-5``) or a description from a JSON file."""
    text, origin = _read_source(str(name_or_path))
    try:
        raw = json.loads(text)
    except json.JSONDecodeError as exc:
        raise SystemDescriptionError(f"{origin}: not valid JSON ({exc})") from exc
    return parse_system(raw, origin=origin)


def parse_system(raw: object, origin: str = "<dict>") -> SystemDescription:
    """Validate a decoded description; errors name the field and what is valid."""
    try:
        return SystemDescription.model_validate(raw)
    except ValidationError as exc:
        lines = []
        for err in exc.errors():
            loc = ".".join(f"[{p}]" if isinstance(p, int) else str(p) for p in err["loc"]).replace(".[", "[")
            lines.append(f"`{loc or '(root)'}`: {err['msg']}")
        raise SystemDescriptionError(f"{origin}: invalid system description\n  " + "\n  ".join(lines)) from None


def _read_source(name: str) -> tuple[str, str]:
    path = Path(name)
    if path.suffix == ".json" or path.exists():
        if not path.is_file():
            raise SystemDescriptionError(f"system description file not found: {path}")
        return path.read_text(), str(path)
    known = reference_systems()
    if name not in known:
        close = difflib.get_close_matches(name, known, n=1)
        hint = f"; did you mean {close[0]!r}?" if close else ""
        raise SystemDescriptionError(f"unknown system {name!r}{hint} (known: {', '.join(known)}; or give a .json path)")
    return resources.files(_REFERENCE_PACKAGE).joinpath(f"{name}.json").read_text(), f"system {name}"
