"""Traces: the shipped Frontier day, the synthetic generator, user CSVs and the load skew."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from lcmesh.twin import traces
from lcmesh.twin.system import load_system, parse_system
from lcmesh.twin.traces import (
    EVAL_SEEDS,
    FRONTIER_DAY,
    TRAIN_SEEDS,
    Trace,
    TraceError,
    load_trace,
    trace_split,
)

SHIPPED_CSV = Path(__file__).parents[2] / "lcmesh" / "twin" / "data" / f"{FRONTIER_DAY}.csv"
HEADER = "time," + ",".join(f"power[{k}]" for k in range(1, 26)) + ",OA Wetbulb Temp"


@pytest.fixture(scope="module")
def lcopt5():
    return load_system("lcopt-5")


@pytest.fixture(scope="module")
def frontier_full():
    return load_system("frontier-full")


def _with(system, **cabinets):
    raw = system.model_dump(mode="json")
    raw["cabinets"].update(cabinets)
    return parse_system(raw)


def _raw_day() -> np.ndarray:
    return np.loadtxt(SHIPPED_CSV, delimiter=",", skiprows=1)


def _write_csv(tmp_path: Path, header: str, rows: list[str]) -> Path:
    path = tmp_path / "trace.csv"
    path.write_text("\n".join([header, *rows]) + "\n")
    return path


def _good_rows(n: int = 5, step: float = 15.0) -> list[str]:
    return [f"{i * step}," + ",".join(["600000.0"] * 25) + ",10.0" for i in range(n)]


# --- the shipped day -------------------------------------------------------------------


@pytest.mark.parametrize("name", ["lcopt-5", "frontier-full"])
def test_shapes(name):
    system = load_system(name)
    trace = load_trace(FRONTIER_DAY, system)
    c, b, g = system.cabinets.count, system.cabinets.branches, system.cabinets.blade_groups_per_branch
    assert trace.n_steps == 5760  # 5,761 rows: the last is the end point of the day
    assert trace.step_s == 15.0
    assert trace.cabinet_load_w.shape == (5760, c) and trace.cabinet_load_w.dtype == np.float64
    assert trace.wet_bulb_k.shape == (5760,)
    assert (trace.branches, trace.blade_groups_per_branch) == (b, g)
    assert trace.blade_power_w(0).shape == (c * b * g,)
    assert trace.branch_power_w(0).shape == (c, b)


def test_columns_map_to_cabinets_scaled_by_design_heat(lcopt5):
    raw = _raw_day()
    system = _with(lcopt5, design_heat_w=325e3)
    trace = load_trace(FRONTIER_DAY, system)
    np.testing.assert_allclose(trace.cabinet_load_w, raw[:-1, 1:6] * 0.5, rtol=1e-12)
    np.testing.assert_allclose(trace.wet_bulb_k, raw[:-1, -1] + 273.15, rtol=1e-12)


def test_cabinets_beyond_columns_reuse_them_time_shifted(lcopt5):
    raw = _raw_day()[:-1]
    system = _with(lcopt5, count=30)
    trace = load_trace(FRONTIER_DAY, system)
    scale = system.cabinets.design_heat_w / 650e3
    reused, source = trace.cabinet_load_w[:, 27], raw[:, 3] * scale  # cabinet 27 takes power[3]
    assert not np.allclose(reused, source)
    shifts = [s for s in range(1, 5760) if np.array_equal(reused, np.roll(source, s))]
    assert len(shifts) == 1 and 240 <= shifts[0] <= 5520  # between 1 h and 23 h


def test_wet_bulb_offset_adds_exactly_15_k(lcopt5):
    plain = load_trace(FRONTIER_DAY, lcopt5)
    hot = load_trace(FRONTIER_DAY, lcopt5, wet_bulb_offset_k=15.0)
    np.testing.assert_allclose(hot.wet_bulb_k - plain.wet_bulb_k, 15.0, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(hot.cabinet_load_w, plain.cabinet_load_w)


# --- the skew ---------------------------------------------------------------------------


@pytest.mark.parametrize("spec", [FRONTIER_DAY, "synthetic:7"])
def test_blade_powers_sum_to_cabinet_load(frontier_full, spec):
    trace = load_trace(spec, frontier_full)
    c, b = frontier_full.cabinets.count, frontier_full.cabinets.branches
    out = np.empty(frontier_full.n_blade_groups)
    for step in range(trace.n_steps):
        blades = trace.blade_power_w(step, out).reshape(c, b, -1)
        np.testing.assert_allclose(blades.sum(axis=(1, 2)), trace.cabinet_load_w[step], rtol=1e-6)
        if step % 500 == 0:
            np.testing.assert_allclose(blades.sum(axis=2), trace.branch_power_w(step), rtol=1e-9)
    assert (out > 0).all()


def test_blade_groups_within_a_branch_are_skewed(frontier_full):
    data = load_trace(FRONTIER_DAY, frontier_full).blade_power_w(100).reshape(25 * 3, 133)
    lcopt = load_trace(FRONTIER_DAY, frontier_full, scenario="lcopt").blade_power_w(100).reshape(25 * 3, 133)
    assert (data.max(axis=1) / data.min(axis=1) > 1.2).all()  # lognormal sigma 0.094 over 133 groups: about 1.6
    assert (lcopt.max(axis=1) / lcopt.min(axis=1) > 1.5).all()  # sigma 0.3: about 4-7


def test_group_spread_is_the_datas_spread_between_cdus():
    raw = np.loadtxt(SHIPPED_CSV, delimiter=",", skiprows=1)[:, 1:26]
    log_ratio = np.log(raw / raw.mean(axis=1, keepdims=True))
    assert np.median(log_ratio.std(axis=1)) == pytest.approx(traces._DATA_GROUP_SHARE_SIGMA, abs=0.001)


def test_default_scenario_carries_the_real_loads_and_weather(lcopt5):
    trace = load_trace(FRONTIER_DAY, lcopt5)
    raw = np.loadtxt(SHIPPED_CSV, delimiter=",", skiprows=1)
    np.testing.assert_allclose(trace.cabinet_load_w, raw[:-1, 1:6], rtol=1e-12)  # watts as recorded
    np.testing.assert_allclose(trace.wet_bulb_k, raw[:-1, 26] + 273.15, rtol=0, atol=1e-9)
    assert trace.scenario == "frontier"


def test_data_branch_shares_follow_other_cdu_columns(lcopt5):
    trace = load_trace(FRONTIER_DAY, lcopt5)
    raw = np.loadtxt(SHIPPED_CSV, delimiter=",", skiprows=1)[:-1, 1:26]
    shares = trace.branch_shares(np.arange(trace.n_steps))
    columns = raw[:, :15].reshape(-1, 5, 3)  # branch j of cabinet i follows column 3 i + j
    np.testing.assert_allclose(shares, columns / columns.sum(axis=2, keepdims=True), rtol=1e-12)
    spread = shares.max(axis=2) - shares.min(axis=2)
    assert 0.005 < np.median(spread) < 0.1  # the CDUs move together: branches differ by a few percent
    assert spread.max() > 0.1  # cabinet 5 holds power[14], the day's low column


def test_synthetic_branch_shares_come_from_the_data(lcopt5):
    day = load_trace(FRONTIER_DAY, lcopt5).branch_shares(np.arange(5760))
    for seed in (3, 4):
        shares = load_trace(f"synthetic:{seed}", lcopt5).branch_shares(np.arange(5760))
        np.testing.assert_allclose(shares.sum(axis=2), 1.0, rtol=1e-12)
        assert day.min() - 0.1 < shares.min() and shares.max() < day.max() + 0.1
        assert not np.allclose(shares, day)


def test_lcopt_branch_shares_differ_and_rotate(lcopt5):
    trace = load_trace(FRONTIER_DAY, lcopt5, scenario="lcopt")
    shares = np.stack([trace.branch_power_w(k) / trace.cabinet_load_w[k][:, None] for k in range(trace.n_steps)])
    np.testing.assert_allclose(shares.sum(axis=2), 1.0, rtol=1e-12)
    np.testing.assert_allclose(shares, trace.branch_shares(np.arange(trace.n_steps)), rtol=1e-12)
    spread = shares.max(axis=2) - shares.min(axis=2)
    assert spread.min() > 0.1 and np.median(spread) > 0.25  # skewed at every step, less mid-rotation
    for cabinet in range(lcopt5.cabinets.count):
        most_loaded = shares[:, cabinet].argmax(axis=1)
        assert set(most_loaded.tolist()) == {0, 1, 2}, f"cabinet {cabinet}: every branch leads at some time"
    assert not np.allclose(shares[:, 0], shares[:, 1])  # cabinets have different phases


def test_lcopt_branch_shares_change_smoothly(lcopt5):
    trace = load_trace(FRONTIER_DAY, lcopt5, scenario="lcopt")
    shares = trace.branch_shares(np.arange(trace.n_steps))
    # 5 min smoothstep (max slope 1.5), <= 0.85 share swing (B = 3: about 0.03 <-> 0.81):
    # at most 1.5 * 0.85 / 20 = 0.064 a step; a jump would move up to 0.8 at once
    assert np.abs(np.diff(shares, axis=0)).max() < 0.07


def test_lcopt_skew_depends_on_load_skew_seed(lcopt5):
    a = load_trace(FRONTIER_DAY, lcopt5, scenario="lcopt")
    b = load_trace(FRONTIER_DAY, lcopt5.model_copy(update={"load_skew_seed": 1}), scenario="lcopt")
    np.testing.assert_array_equal(a.cabinet_load_w, b.cabinet_load_w)
    assert not np.allclose(a.branch_shares(0), b.branch_shares(0))


def test_lcopt_scenario_is_the_papers_hardening(lcopt5):
    plain = load_trace(FRONTIER_DAY, lcopt5)
    hard = load_trace(FRONTIER_DAY, lcopt5, scenario="lcopt")
    np.testing.assert_allclose(hard.wet_bulb_k - plain.wet_bulb_k, 15.0, rtol=0, atol=1e-9)
    np.testing.assert_allclose(hard.cabinet_load_w, plain.cabinet_load_w * 225.0 / 650.0, rtol=1e-12)
    paper = load_trace(FRONTIER_DAY, load_system("lcopt-5-paper"), scenario="lcopt")  # scaled once, not twice
    np.testing.assert_allclose(paper.cabinet_load_w, hard.cabinet_load_w, rtol=1e-12)
    assert hard.cabinet_load_w.mean() == pytest.approx(225e3, rel=0.01)


def test_design_day_wet_bulb(lcopt5):
    trace = load_trace(FRONTIER_DAY, lcopt5, scenario="design-day")
    day = traces.DESIGN_DAYS["knoxville-0.4"]
    hourly = (trace.wet_bulb_k - 273.15).reshape(24, -1)
    assert hourly.max() == pytest.approx(day.peak_wet_bulb_c, abs=1e-9)
    assert hourly.max() - hourly.min() == pytest.approx(day.daily_range_k, abs=1e-9)
    assert 13 <= hourly.max(axis=1).argmax() <= 15  # warmest mid-afternoon
    assert 4 <= hourly.min(axis=1).argmin() <= 5  # coolest at dawn
    np.testing.assert_array_equal(trace.cabinet_load_w, load_trace(FRONTIER_DAY, lcopt5).cabinet_load_w)


def test_unknown_scenario_names_the_known_ones(lcopt5):
    with pytest.raises(TraceError, match="did you mean 'design-day'.*frontier, design-day, lcopt"):
        load_trace(FRONTIER_DAY, lcopt5, scenario="design_day")


# --- synthetic traces -------------------------------------------------------------------


def test_synthetic_is_deterministic(frontier_full):
    a = load_trace("synthetic:42", frontier_full)
    b = load_trace("synthetic:42", frontier_full)
    c = load_trace("synthetic:43", frontier_full)
    np.testing.assert_array_equal(a.cabinet_load_w, b.cabinet_load_w)
    np.testing.assert_array_equal(a.wet_bulb_k, b.wet_bulb_k)
    for step in (0, 1234, 5759):
        np.testing.assert_array_equal(a.blade_power_w(step), b.blade_power_w(step))
    assert not np.allclose(a.cabinet_load_w, c.cabinet_load_w)
    assert not np.allclose(a.wet_bulb_k, c.wet_bulb_k)
    assert not np.allclose(a.branch_shares(0), c.branch_shares(0))


@pytest.mark.parametrize("seed", [0, 1, 2, 1000, 1999])
def test_synthetic_statistics(seed):
    system = load_system("lcopt-25")
    trace = load_trace(f"synthetic:{seed}", system)
    # in fractions of a cabinet's peak: the generator's levels before the stretch to the mean
    load = trace.cabinet_load_w / (system.cabinets.design_heat_w * traces._PEAK_OVER_MEAN)
    assert trace.n_steps == 5760
    assert load.min() >= 0.05 - 1e-12 and load.max() <= 1.15 + 1e-12
    assert 0.05 < (load < 0.25).mean() < 0.9, "idle phases present"
    assert 0.001 < (load > 1.0).mean() < 0.15, "short bursts present, but rare"
    corr = np.corrcoef(load.T)[np.triu_indices(25, 1)].mean()
    assert corr > 0.3, "cabinets move together"
    hourly_c = (trace.wet_bulb_k - 273.15).reshape(24, -1).mean(axis=1)
    assert 2 <= hourly_c.argmin() <= 10, "coldest in the early morning"
    assert 2.0 < hourly_c.max() - hourly_c.min() < 16.0
    assert -15 < hourly_c.min() and hourly_c.max() < 35


def test_synthetic_hours(lcopt5):
    trace = load_trace("synthetic:5", lcopt5, hours=2)
    assert trace.n_steps == 480 and trace.cabinet_load_w.shape == (480, 5)
    assert load_trace(FRONTIER_DAY, lcopt5, hours=1).n_steps == 240


@pytest.mark.parametrize("spec", ["synthetic:abc", "synthetic:-1", "frontier-2024-04-08", "missing.csv"])
def test_bad_specs(lcopt5, spec):
    with pytest.raises(TraceError, match="synthetic|not found|unknown trace"):
        load_trace(spec, lcopt5)


def test_unknown_name_suggests_close_one(lcopt5):
    with pytest.raises(TraceError, match="did you mean 'frontier-2024-04-07'"):
        load_trace("frontier-2024-04-08", lcopt5)


def test_hours_longer_than_file(lcopt5):
    with pytest.raises(TraceError, match="holds 24.00 h"):
        load_trace(FRONTIER_DAY, lcopt5, hours=25)


# --- slicing and the fast path ----------------------------------------------------------


def test_slice_continues_schedule(frontier_full):
    trace = load_trace(FRONTIER_DAY, frontier_full)
    window = trace.slice(1000, 200)
    assert isinstance(window, Trace) and window.n_steps == 200
    np.testing.assert_array_equal(window.cabinet_load_w, trace.cabinet_load_w[1000:1200])
    np.testing.assert_array_equal(window.wet_bulb_k, trace.wet_bulb_k[1000:1200])
    for k in (0, 77, 199):
        np.testing.assert_array_equal(window.blade_power_w(k), trace.blade_power_w(1000 + k))
    np.testing.assert_array_equal(window.slice(50, 10).blade_power_w(3), trace.blade_power_w(1053))
    for start, n in ((-1, 10), (5700, 100), (0, 0)):
        with pytest.raises(TraceError, match="slice"):
            trace.slice(start, n)
    with pytest.raises(IndexError, match="step"):
        window.blade_power_w(200)


def test_blade_power_out_is_written_in_place(frontier_full):
    trace = load_trace(FRONTIER_DAY, frontier_full)
    out = np.zeros(frontier_full.n_blade_groups)
    returned = trace.blade_power_w(321, out=out)
    assert returned is out
    np.testing.assert_array_equal(out, trace.blade_power_w(321))
    with pytest.raises(ValueError, match="out"):
        trace.blade_power_w(0, out=np.empty(10))


def test_arrays_are_read_only(lcopt5):
    trace = load_trace(FRONTIER_DAY, lcopt5)
    with pytest.raises(ValueError):
        trace.cabinet_load_w[0, 0] = 0.0


# --- the split ----------------------------------------------------------------------------


def test_split_keeps_training_off_evaluation_traces():
    train, evaluation = trace_split("train"), trace_split("eval")
    assert train == [f"synthetic:{s}" for s in TRAIN_SEEDS] and len(train) == 1000
    assert evaluation[0] == FRONTIER_DAY and len(evaluation) == 1 + len(EVAL_SEEDS)
    assert not set(train) & set(evaluation)
    with pytest.raises(ValueError, match="'train' or 'eval'"):
        trace_split("test")  # type: ignore[arg-type]


# --- user CSVs ----------------------------------------------------------------------------


def test_user_csv_with_few_columns_and_coarse_step(tmp_path, lcopt5):
    rows = [f"{60.0 * i},{100e3 * (i + 1)},{200e3},{5.0 + i}" for i in range(5)]
    path = _write_csv(tmp_path, "time,power[1],power[2],OA Wetbulb Temp", rows)
    system = _with(lcopt5, design_heat_w=650e3)  # scale 1: the CSV's watts as they are
    trace = load_trace(str(path), system)
    assert trace.n_steps == 16  # 4 minutes at 15 s, interpolated
    np.testing.assert_allclose(trace.cabinet_load_w[:5, 0], [100e3, 125e3, 150e3, 175e3, 200e3])
    np.testing.assert_allclose(trace.cabinet_load_w[:, 1], 200e3)  # cabinet 1 takes power[2]
    np.testing.assert_allclose(trace.wet_bulb_k[4], 6.0 + 273.15)
    assert trace.name == str(path)


def test_user_csv_same_format_as_shipped_day(tmp_path, lcopt5):
    path = tmp_path / "copy.csv"
    path.write_bytes(SHIPPED_CSV.read_bytes())
    np.testing.assert_array_equal(
        load_trace(str(path), lcopt5).cabinet_load_w, load_trace(FRONTIER_DAY, lcopt5).cabinet_load_w
    )


def _replace_cell(rows: list[str], row: int, col: int, value: str) -> list[str]:
    cells = rows[row].split(",")
    cells[col] = value
    return [*rows[:row], ",".join(cells), *rows[row + 1 :]]


CORRUPT_CASES = {
    "missing time": (HEADER.replace("time,", "t,"), _good_rows(), r"missing column\(s\) time"),
    "missing wet bulb": (HEADER.replace("OA Wetbulb Temp", "wb"), _good_rows(), "missing column.*OA Wetbulb Temp"),
    "no power": ("time,OA Wetbulb Temp", [f"{15 * i},10" for i in range(3)], r"missing column.*power\[1\]"),
    "power gap": (HEADER.replace("power[7],", "other,"), _good_rows(), r"missing column\(s\) power\[7\]"),
    "one row": (HEADER, _good_rows(1), r"at least 2 data rows \(start and end time\), got 1"),
    "non-numeric": (HEADER, _replace_cell(_good_rows(), 2, 4, "abc"), r"line 4, column 'power\[4\]': 'abc'"),
    "nan": (HEADER, _replace_cell(_good_rows(), 1, 26, "nan"), "line 3, column 'OA Wetbulb Temp': 'nan'"),
    "empty cell": (HEADER, _replace_cell(_good_rows(), 3, 0, ""), "line 5, column 'time': ''"),
    "short row": (HEADER, [*_good_rows(3), "45.0,1"], "line 5: 2 fields"),
    "time goes back": (HEADER, _replace_cell(_good_rows(), 3, 0, "15.0"), "line 5: `time` 15.0 is not after 30.0"),
    "uneven time": (HEADER, _replace_cell(_good_rows(), 4, 0, "70.0"), "line 6: time step 25.0 s differs"),
    "negative power": (HEADER, _replace_cell(_good_rows(), 2, 3, "-5"), r"line 4, column 'power\[3\]'.*>= 0"),
    "wet bulb too hot": (HEADER, _replace_cell(_good_rows(), 0, 26, "55"), r"line 2.*outside \[-40.0, 50.0\]"),
    "wet bulb too cold": (HEADER, _replace_cell(_good_rows(), 1, 26, "-41"), r"line 3.*outside \[-40.0, 50.0\]"),
}


@pytest.mark.parametrize("case", CORRUPT_CASES)
def test_corrupt_csv_raises_trace_error(tmp_path, lcopt5, case):
    header, rows, message = CORRUPT_CASES[case]
    path = _write_csv(tmp_path, header, rows)
    with pytest.raises(TraceError, match=message) as info:
        load_trace(str(path), lcopt5)
    assert str(path) in str(info.value)


def test_missing_file(tmp_path, lcopt5):
    with pytest.raises(TraceError, match="trace file not found"):
        load_trace(str(tmp_path / "nope.csv"), lcopt5)
