"""FMU runner: the only module that imports fmpy.

Drives an FMI 2.0 co-simulation FMU through the raw fmi2 C functions with pre-allocated
numpy buffers (fmpy's list-based ``setReal``/``getReal`` build ctypes arrays on every call),
resets without re-loading the library, and saves/restores FMU state for what-if look-ahead.

Our generated FMUs name arrays in structured form (``blade_temp_k[3]``). A third-party FMU
(e.g. an LC-Opt-style Dymola export) plugs in through a *variable map*: a JSON object from our
block names to its variable names, see docs/twin.md#third-party-fmus.
"""

from __future__ import annotations

import ctypes
import json
import re
import shutil
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave

_INDEXED = re.compile(r"^(?P<base>.+)\[(?P<idx>[0-9, ]+)\]$")
_UINT_P = ctypes.POINTER(ctypes.c_uint)
_DOUBLE_P = ctypes.POINTER(ctypes.c_double)


class FmuError(RuntimeError):
    """An FMU call failed or the FMU lacks what the caller asked for."""


class Channel:
    """A fixed set of value references with a pre-allocated value buffer."""

    def __init__(self, runner: "FmuRunner", vrs: np.ndarray):
        self._runner = runner
        self.vrs = np.ascontiguousarray(vrs, dtype=np.uint32)
        self.values = np.zeros(len(self.vrs), dtype=np.float64)
        self._vr_p = self.vrs.ctypes.data_as(_UINT_P)
        self._val_p = self.values.ctypes.data_as(_DOUBLE_P)
        self._n = ctypes.c_size_t(len(self.vrs))

    def read(self) -> np.ndarray:
        """Fill `values` from the FMU and return it (the same array, not a copy)."""
        status = self._runner._get_real(self._runner._component, self._vr_p, self._n, self._val_p)
        if status > 1:
            raise FmuError(f"fmi2GetReal failed with status {status}")
        return self.values

    def write(self) -> None:
        """Send `values` to the FMU."""
        status = self._runner._set_real(self._runner._component, self._vr_p, self._n, self._val_p)
        if status > 1:
            raise FmuError(f"fmi2SetReal failed with status {status}")


class FmuState:
    """An opaque saved FMU state; free it with `FmuRunner.free_state` or let the runner do it on close."""

    def __init__(self, pointer: ctypes.c_void_p, time: float):
        self.pointer = pointer
        self.time = time


class FmuRunner:
    """One instance of an FMI 2.0 CS FMU, driven through raw fmi2 calls."""

    def __init__(
        self,
        fmu_path: str | Path,
        *,
        variable_map: Mapping[str, str | Sequence[str]] | str | Path | None = None,
        instance_name: str = "lcmesh",
    ):
        self.path = Path(fmu_path)
        if not self.path.is_file():
            raise FmuError(f"FMU not found: {self.path}")
        self.model_description = read_model_description(str(self.path))
        if self.model_description.coSimulation is None:
            raise FmuError(f"{self.path.name} is not a co-simulation FMU")
        self._unzip_dir = extract(str(self.path))
        self._fmu = FMU2Slave(
            guid=self.model_description.guid,
            unzipDirectory=self._unzip_dir,
            modelIdentifier=self.model_description.coSimulation.modelIdentifier,
            instanceName=instance_name,
        )
        self._fmu.instantiate()
        self._component = self._fmu.component
        raw = self._fmu._functions
        self._set_real, self._get_real = raw["fmi2SetReal"], raw["fmi2GetReal"]
        self._do_step = raw["fmi2DoStep"]
        self._real_vrs = {
            v.name: v.valueReference for v in self.model_description.modelVariables if v.type == "Real"
        }
        self._blocks = _index_blocks(self._real_vrs)
        self._map = _load_variable_map(variable_map)
        self._states: list[FmuState] = []
        self.time = 0.0
        self._closed = False

    # --- variables -------------------------------------------------------
    def has(self, block: str) -> bool:
        """Whether the FMU provides `block`; a variable-map entry naming unknown variables raises."""
        if block in self._map:
            self.vrs(block)
            return True
        return block in self._blocks or block in self._real_vrs

    def vrs(self, block: str) -> np.ndarray:
        """Value references of a block (``blade_temp_k``) or a single variable, in index order."""
        if block in self._map:
            names = self._map[block]
            missing = [n for n in names if n not in self._real_vrs]
            if missing:
                raise FmuError(f"variable map entry {block!r} names unknown FMU variables: {missing[:5]}")
            return np.array([self._real_vrs[n] for n in names], dtype=np.uint32)
        if block in self._blocks:
            return self._blocks[block]
        if block in self._real_vrs:
            return np.array([self._real_vrs[block]], dtype=np.uint32)
        raise FmuError(f"{self.path.name} has no Real variable or array {block!r}")

    def channel(self, *blocks: str) -> Channel:
        """One buffer over the concatenated value references of `blocks`."""
        return Channel(self, np.concatenate([self.vrs(b) for b in blocks]))

    def start_value(self, name: str) -> float | None:
        for v in self.model_description.modelVariables:
            if v.name == name and v.start is not None:
                return float(v.start)
        return None

    # --- lifecycle -------------------------------------------------------
    def initialize(self, parameters: Mapping[str, float] | None = None, start_time: float = 0.0) -> None:
        """Set parameters, then run the FMU's initialization."""
        self._fmu.setupExperiment(startTime=start_time)
        if parameters:
            names = list(parameters)
            channel = Channel(self, np.concatenate([self.vrs(n) for n in names]))
            channel.values[:] = [float(parameters[n]) for n in names]
            channel.write()
        self._fmu.enterInitializationMode()
        self._fmu.exitInitializationMode()
        self.time = start_time

    def reset(self, parameters: Mapping[str, float] | None = None) -> None:
        """Back to the initial state without re-loading the library."""
        self._fmu.reset()
        self.initialize(parameters)

    def do_step(self, step_s: float) -> None:
        status = self._do_step(self._component, ctypes.c_double(self.time), ctypes.c_double(step_s), 1)
        if status > 1:
            raise FmuError(f"fmi2DoStep failed at t = {self.time:.0f} s with status {status}")
        self.time += step_s

    # --- fmpy's list-based API (kept for the benchmark's comparison) --------
    def set_real_list(self, vrs: Sequence[int], values: Sequence[float]) -> None:
        self._fmu.setReal(list(vrs), list(values))

    def get_real_list(self, vrs: Sequence[int]) -> list[float]:
        return self._fmu.getReal(list(vrs))

    def do_step_list(self, step_s: float) -> None:
        self._fmu.doStep(currentCommunicationPoint=self.time, communicationStepSize=step_s)
        self.time += step_s

    # --- state -------------------------------------------------------------
    def save_state(self) -> FmuState:
        pointer = ctypes.c_void_p()
        self._check(self._fmu._functions["fmi2GetFMUstate"](self._component, ctypes.byref(pointer)), "GetFMUstate")
        state = FmuState(pointer, self.time)
        self._states.append(state)
        return state

    def restore_state(self, state: FmuState) -> None:
        self._check(self._fmu._functions["fmi2SetFMUstate"](self._component, state.pointer), "SetFMUstate")
        self.time = state.time

    def free_state(self, state: FmuState) -> None:
        if state in self._states:
            self._states.remove(state)
            self._fmu._functions["fmi2FreeFMUstate"](self._component, ctypes.byref(state.pointer))

    def serialize_state(self, state: FmuState) -> bytes:
        """The state as bytes (to store, or to send to another process running the same FMU)."""
        fns = self._fmu._functions
        size = ctypes.c_size_t()
        self._check(fns["fmi2SerializedFMUstateSize"](self._component, state.pointer, ctypes.byref(size)), "Size")
        buffer = ctypes.create_string_buffer(size.value)
        self._check(fns["fmi2SerializeFMUstate"](self._component, state.pointer, buffer, size), "SerializeFMUstate")
        return buffer.raw

    def deserialize_state(self, data: bytes, time: float = 0.0) -> FmuState:
        """A state from `serialize_state` bytes; corrupt or foreign bytes raise FmuError."""
        pointer = ctypes.c_void_p()
        buffer = ctypes.create_string_buffer(bytes(data), len(data))
        status = self._fmu._functions["fmi2DeSerializeFMUstate"](
            self._component, buffer, ctypes.c_size_t(len(data)), ctypes.byref(pointer)
        )
        self._check(status, "DeSerializeFMUstate")
        state = FmuState(pointer, time)
        self._states.append(state)
        return state

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        for state in list(self._states):
            self.free_state(state)
        try:
            self._fmu.terminate()
        finally:
            self._fmu.freeInstance()
            shutil.rmtree(self._unzip_dir, ignore_errors=True)

    def __enter__(self) -> "FmuRunner":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _check(self, status: int, what: str) -> None:
        if status > 1:
            raise FmuError(f"fmi2{what} failed with status {status}")


def validate_fmu(fmu_path: str | Path) -> list[str]:
    """Problems fmpy's validator finds in an FMU's model description (empty when clean)."""
    from fmpy.validation import validate_fmu as _validate

    return [str(p) for p in _validate(str(fmu_path))]


def _index_blocks(real_vrs: Mapping[str, int]) -> dict[str, np.ndarray]:
    """Group structured names ``base[i]`` / ``base[i,j]`` into arrays in row-major index order."""
    groups: dict[str, list[tuple[tuple[int, ...], int]]] = {}
    for name, vr in real_vrs.items():
        match = _INDEXED.match(name)
        if match:
            idx = tuple(int(x) for x in match["idx"].split(","))
            groups.setdefault(match["base"], []).append((idx, vr))
    return {base: np.array([vr for _, vr in sorted(items)], dtype=np.uint32) for base, items in groups.items()}


def _load_variable_map(variable_map) -> dict[str, list[str]]:
    if variable_map is None:
        return {}
    if isinstance(variable_map, (str, Path)):
        path = Path(variable_map)
        try:
            variable_map = json.loads(path.read_text())
        except (OSError, json.JSONDecodeError) as exc:
            raise FmuError(f"cannot read variable map {path}: {exc}") from exc
    if not isinstance(variable_map, Mapping):
        raise FmuError("a variable map must be a JSON object {block: name or [names]}")
    out = {}
    for block, names in variable_map.items():
        if isinstance(names, str):
            names = [names]
        if not isinstance(names, Sequence) or not all(isinstance(n, str) for n in names):
            raise FmuError(f"variable map entry {block!r} must be a name or a list of names")
        out[block] = list(names)
    return out
