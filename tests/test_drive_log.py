"""Drive logs (SPEC §4): exact round trips in CSV, Parquet and MDF4, refusal of bad logs with one
line naming file/row/column, NaN handling of optional columns (batches of drives: test_drive_batching.py)."""

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import jaxmodel
from identification import DriveLogError
from identification.drive_log import (INTEGER_COLUMNS, Drive, drive_from_columns, read_drive, read_table, wrap_deg,
                                      wrap_rad, write_drive)

from drives import assert_same, synthetic_columns

FORMATS = ("csv", "parquet", "mf4")


def with_optional(cols):
    n = len(cols["time_s"])
    out = dict(cols)
    out["map_heading_deg"] = np.linspace(-170.0, 190.0, n)
    out["map_valid"] = (np.arange(n) % 3 == 0).astype(np.int64)
    out["compass_unreliable_area"] = (np.arange(n) % 2 == 0).astype(np.int64)
    out["fix_east_m"] = np.linspace(0.0, 50.0, n)
    out["fix_north_m"] = np.linspace(5.0, -5.0, n)
    out["fix_valid"] = (np.arange(n) % 10 == 0).astype(np.int64)
    return out


# ----------------------------------------------------------------------------------------------
# round trips


@pytest.mark.parametrize("fmt", FORMATS)
def test_round_trip_exact(tmp_path, fmt):
    cols = with_optional(synthetic_columns())
    cols["compass_x"][[3, 7]] = np.nan
    cols["compass_y"][9] = np.inf
    cols["extra_signal"] = np.linspace(0, 1, len(cols["time_s"])) ** 3
    assert np.any(np.diff(cols["left_pulses"]) < 0), "the counters must wrap in this drive"
    path = write_drive(tmp_path / f"drive.{fmt}", cols)
    back = read_table(path)
    assert list(back)[: len(cols)] == list(cols)
    for k, v in cols.items():
        assert_same(back[k], v, k)
    for k in INTEGER_COLUMNS:
        assert back[k].dtype == np.int64, k  # integer counters and flags come back as integers
    assert [p.name for p in tmp_path.iterdir()] == [f"drive.{fmt}"]  # no temporary left behind


@pytest.mark.parametrize("fmt", FORMATS)
def test_round_trip_large_counters_and_awkward_floats(tmp_path, fmt):
    n = 6
    cols = {
        "time_s": np.array([-1.0, 0.1, 0.30000000000000004, 1e-9 + 1, 2.5e6, 2.5e6 + 1e-3]),
        "left_pulses": np.array([0, 1, 2**31, 2**40, 2**53 - 1, 7], dtype=np.int64),
        "right_pulses": np.array([65535, 0, 1, 65534, 65535, 0], dtype=np.int64),
        "compass_x": np.array([1e-300, -0.0, 5e-324, 1.7976931348623157e308, np.nan, -np.inf]),
        "compass_y": np.array([math.pi, -math.e, 1 / 3, 2 / 3, 0.1 + 0.2, np.nan]),
    }
    back = read_table(write_drive(tmp_path / f"d.{fmt}", cols))
    for k, v in cols.items():
        assert_same(back[k], v, k)
    assert back["left_pulses"].dtype == np.int64
    assert int(back["left_pulses"][4]) == 2**53 - 1
    assert len(back["time_s"]) == n


@pytest.mark.parametrize("fmt", FORMATS)
def test_float_pulse_columns_are_stored_as_integers(tmp_path, fmt):
    cols = synthetic_columns(n=10)
    cols["left_pulses"] = cols["left_pulses"].astype(np.float64)
    cols["map_valid"] = np.ones(10)
    cols["map_heading_deg"] = np.zeros(10)
    back = read_table(write_drive(tmp_path / f"d.{fmt}", cols))
    assert back["left_pulses"].dtype == np.int64 and back["map_valid"].dtype == np.int64
    assert_same(back["left_pulses"], cols["left_pulses"].astype(np.int64))


@pytest.mark.parametrize("fmt", FORMATS)
def test_overwrite_is_atomic_and_complete(tmp_path, fmt):
    path = tmp_path / f"d.{fmt}"
    write_drive(path, synthetic_columns(n=50))
    cols = synthetic_columns(n=20, seed=3)
    write_drive(path, cols)
    assert_same(read_table(path)["time_s"], cols["time_s"])
    with pytest.raises(ValueError):
        write_drive(tmp_path / f"bad.{fmt}", {"time_s": np.arange(3.0), "compass_x": np.arange(4.0)})
    assert sorted(p.name for p in tmp_path.iterdir()) == [f"d.{fmt}"]


_finite = st.floats(allow_nan=False, allow_infinity=True, width=64)


@pytest.mark.parametrize("fmt", FORMATS)
@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_round_trip_random_values(tmp_path, fmt, data):
    n = data.draw(st.integers(1, 12))
    floats = st.one_of(_finite, st.just(float("nan")))
    cols = {
        "time_s": np.array(data.draw(st.lists(_finite, min_size=n, max_size=n))),
        "left_pulses": np.array(data.draw(st.lists(st.integers(0, 2**53), min_size=n, max_size=n)), dtype=np.int64),
        "right_pulses": np.array(data.draw(st.lists(st.integers(-(2**62), 2**62), min_size=n, max_size=n)),
                                 dtype=np.int64),
        "compass_x": np.array(data.draw(st.lists(floats, min_size=n, max_size=n))),
        "compass_y": np.array(data.draw(st.lists(floats, min_size=n, max_size=n))),
    }
    path = tmp_path / f"random.{fmt}"
    back = read_table(write_drive(path, cols))
    for k, v in cols.items():
        assert_same(back[k], v, k)


# ----------------------------------------------------------------------------------------------
# the Drive


def test_read_drive_builds_inputs(tmp_path):
    cols = with_optional(synthetic_columns())
    cols["compass_x"][[4, 5]] = np.nan
    cols["compass_y"][20] = -np.inf
    cols["map_heading_deg"][0] = np.nan   # map_valid is 1 at row 0: becomes invalid
    cols["fix_north_m"][10] = np.nan      # fix_valid is 1 at row 10: becomes invalid
    cols["ref_heading_deg"][30] = np.nan
    path = write_drive(tmp_path / "d.parquet", cols)
    drive = read_drive(path)
    assert isinstance(drive, Drive)
    inp = drive.inputs
    assert isinstance(inp, jaxmodel.Inputs)
    n = len(cols["time_s"])
    for k in jaxmodel.Inputs._fields:
        v = getattr(inp, k)
        assert isinstance(v, np.ndarray) and v.dtype == np.float64 and v.shape == (n,), k
    assert_same(inp.left_pulses, cols["left_pulses"].astype(np.float64))
    assert np.isnan(inp.compass_x[4]) and np.isinf(inp.compass_y[20])  # kept: the model skips them
    md = drive.metadata
    assert md["path"] == str(path) and md["n_samples"] == n and md["format"] == "parquet"
    assert md["columns"] == list(cols)
    assert md["bad_compass_samples"] == 3
    assert md["missing_ref_samples"] == 1
    assert md["map_invalidated_samples"] == 1 and md["fix_invalidated_samples"] == 1
    # map heading in rad, wrapped to (-pi, pi]; NaN rows invalid with a finite heading
    expected = wrap_rad(np.deg2rad(cols["map_heading_deg"]))
    ok = np.isfinite(expected)
    assert np.allclose(inp.map_heading[ok], expected[ok], rtol=0, atol=1e-15)
    assert np.all(np.isfinite(inp.map_heading)) and inp.map_valid[0] == 0.0
    assert np.all((inp.map_heading > -np.pi) & (inp.map_heading <= np.pi))
    assert inp.fix_valid[10] == 0.0 and inp.fix_valid[20] == 1.0 and np.all(np.isfinite(inp.fix_north_m))
    # reference in rad, wrapped, NaN kept
    assert np.isnan(drive.ref_heading[30])
    good = np.isfinite(drive.ref_heading)
    assert np.allclose(drive.ref_heading[good], wrap_rad(np.deg2rad(cols["ref_heading_deg"]))[good])
    assert np.all(np.abs(drive.ref_heading[good]) <= np.pi)


def test_optional_columns_absent_default_to_zero():
    cols = synthetic_columns(n=10)
    del cols["ref_heading_deg"]
    drive = drive_from_columns(cols, source="sim")
    assert drive.ref_heading is None and drive.metadata["path"] == "sim"
    for k in ("map_heading", "map_valid", "compass_unreliable_area", "fix_east_m", "fix_north_m", "fix_valid"):
        assert np.all(getattr(drive.inputs, k) == 0.0), k


def test_map_heading_without_valid_column_is_valid_where_finite():
    cols = synthetic_columns(n=5)
    cols["map_heading_deg"] = np.array([10.0, np.nan, 180.0, -180.0, 540.0])
    drive = drive_from_columns(cols)
    assert list(drive.inputs.map_valid) == [1.0, 0.0, 1.0, 1.0, 1.0]
    assert np.allclose(drive.inputs.map_heading, [np.deg2rad(10.0), 0.0, np.pi, np.pi, np.pi])


def test_flags_accept_booleans_in_csv(tmp_path):
    cols = synthetic_columns(n=4)
    path = tmp_path / "flags.csv"
    text = ["time_s,left_pulses,right_pulses,compass_x,compass_y,map_heading_deg,map_valid,compass_unreliable_area"]
    for i in range(4):
        text.append(f"{float(cols['time_s'][i])!r},{cols['left_pulses'][i]},{cols['right_pulses'][i]},1.0,0.0,90,"
                    f"{'true' if i % 2 else 'false'},{i % 2}")
    path.write_text("\n".join(text) + "\n")
    drive = read_drive(path)
    assert list(drive.inputs.map_valid) == [0.0, 1.0, 0.0, 1.0]
    assert list(drive.inputs.compass_unreliable_area) == [0.0, 1.0, 0.0, 1.0]


def test_wrap_helpers():
    x = np.array([-540.0, -180.0, -179.5, 0.0, 180.0, 359.0, 720.0, np.nan])
    assert_same(wrap_deg(x), np.array([180.0, 180.0, -179.5, 0.0, 180.0, -1.0, 0.0, np.nan]))
    assert wrap_rad(-np.pi) == np.pi and wrap_rad(np.pi) == np.pi


# ----------------------------------------------------------------------------------------------
# bad logs


def _write_csv_text(path, header, rows):
    path.write_text(",".join(header) + "\n" + "".join(",".join(str(c) for c in r) + "\n" for r in rows))
    return path


def _bad_cases():
    """(id, column-mutation, expected fragments besides the file name)."""
    def drop(col):
        def f(c):
            del c[col]
        return f

    def setv(col, row, value, dtype=np.float64):
        def f(c):
            c[col] = c[col].astype(dtype)
            c[col][row] = value
        return f

    return [
        ("missing_time", drop("time_s"), ["column", "'time_s'", "missing"]),
        ("missing_left", drop("left_pulses"), ["'left_pulses'", "missing"]),
        ("missing_compass_y", drop("compass_y"), ["'compass_y'", "missing"]),
        ("time_equal", lambda c: c["time_s"].__setitem__(6, c["time_s"][5]), ["row 7", "'time_s'", "strictly increasing"]),
        ("time_backwards", setv("time_s", 4, 0.0), ["row 5", "'time_s'", "strictly increasing"]),
        ("time_nan", setv("time_s", 8, np.nan), ["row 9", "'time_s'", "nan"]),
        ("time_inf", setv("time_s", 2, np.inf), ["row 3", "'time_s'", "inf"]),
        ("pulses_nan", setv("left_pulses", 11, np.nan), ["row 12", "'left_pulses'", "nan"]),
        ("pulses_inf", setv("right_pulses", 3, np.inf), ["row 4", "'right_pulses'", "inf"]),
        ("pulses_fraction", setv("right_pulses", 5, 12.5), ["row 6", "'right_pulses'", "12.5", "integer"]),
        ("pulses_negative", setv("left_pulses", 0, -3, np.int64), ["row 1", "'left_pulses'", "negative"]),
        ("flag_not_binary", lambda c: c.update(map_heading_deg=np.zeros(20), map_valid=np.full(20, 2)),
         ["row 1", "'map_valid'", "0 or 1"]),
    ]


BAD = _bad_cases()


def _apply(case_id, mutate):
    cols = synthetic_columns(n=20)
    mutate(cols)
    return cols


def assert_one_line(exc_info, path, fragments):
    msg = str(exc_info.value)
    assert "\n" not in msg
    assert str(path) in msg
    for frag in fragments:
        assert frag.lower() in msg.lower(), (frag, msg)


@pytest.mark.parametrize("fmt", FORMATS)
@pytest.mark.parametrize("case_id,mutate,fragments", BAD, ids=[b[0] for b in BAD])
def test_bad_log_is_refused(tmp_path, fmt, case_id, mutate, fragments):
    cols = _apply(case_id, mutate)
    if fmt == "mf4" and case_id == "missing_time":
        pytest.skip("an MDF4 group always has its time master")
    path = write_drive(tmp_path / f"bad.{fmt}", cols)
    with pytest.raises(DriveLogError) as info:
        read_drive(path)
    assert_one_line(info, path, fragments)


@pytest.mark.parametrize("case_id,mutate,fragments", BAD, ids=[b[0] for b in BAD])
def test_bad_columns_are_refused_in_memory(case_id, mutate, fragments):
    with pytest.raises(DriveLogError) as info:
        drive_from_columns(_apply(case_id, mutate), source="memory-drive")
    assert_one_line(info, "memory-drive", fragments)


@pytest.mark.parametrize("fmt", FORMATS)
def test_empty_log(tmp_path, fmt):
    cols = {k: v[:0] for k, v in synthetic_columns(n=5).items()}
    path = write_drive(tmp_path / f"empty.{fmt}", cols)
    with pytest.raises(DriveLogError) as info:
        read_drive(path)
    assert_one_line(info, path, ["empty"])


@pytest.mark.parametrize("fmt", FORMATS)
def test_zero_byte_file(tmp_path, fmt):
    path = tmp_path / f"zero.{fmt}"
    path.write_bytes(b"")
    with pytest.raises(DriveLogError) as info:
        read_drive(path)
    assert_one_line(info, path, ["empty"])


@pytest.mark.parametrize("fmt", FORMATS)
@pytest.mark.parametrize("content", [b"\x89PNG\r\n\x1a\n" + bytes(range(256)) * 4, b"MDF     4.10    " + b"\0" * 200,
                                     b"PAR1" + b"\x13" * 100 + b"PAR1"], ids=["binary", "mdf-header", "parquet-magic"])
def test_corrupt_file(tmp_path, fmt, content, capfd):
    path = tmp_path / f"corrupt.{fmt}"
    path.write_bytes(content)
    with pytest.raises(DriveLogError) as info:
        read_drive(path)
    assert_one_line(info, path, [])
    import gc

    gc.collect()
    captured = capfd.readouterr()
    assert captured.err == "" and captured.out == ""  # no library noise on stderr


@pytest.mark.parametrize("fmt", FORMATS)
def test_truncated_file(tmp_path, fmt):
    path = write_drive(tmp_path / f"t.{fmt}", synthetic_columns(n=200))
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    if fmt == "csv":
        # a CSV cut in the middle of a line: the last row has too few fields (or is cut in a number)
        try:
            drive = read_drive(path)
        except DriveLogError as exc:
            assert "\n" not in str(exc) and str(path) in str(exc)
        else:
            assert drive.metadata["n_samples"] < 200
        return
    with pytest.raises(DriveLogError) as info:
        read_drive(path)
    assert_one_line(info, path, [])


def test_unknown_extension(tmp_path):
    path = tmp_path / "drive.txt"
    path.write_text("time_s\n1\n")
    with pytest.raises(DriveLogError) as info:
        read_drive(path)
    assert_one_line(info, path, [".txt", ".csv", ".parquet", ".mf4"])
    with pytest.raises(DriveLogError):
        write_drive(tmp_path / "out.xlsx", synthetic_columns(n=3))
    assert not (tmp_path / "out.xlsx").exists()


def test_missing_file(tmp_path):
    with pytest.raises(DriveLogError) as info:
        read_drive(tmp_path / "nope.csv")
    assert_one_line(info, tmp_path / "nope.csv", ["not found"])


def test_csv_row_with_wrong_field_count(tmp_path):
    header = ["time_s", "left_pulses", "right_pulses", "compass_x", "compass_y"]
    path = _write_csv_text(tmp_path / "ragged.csv", header,
                           [[0.0, 1, 1, 1.0, 0.0], [0.1, 2, 2, 1.0, 0.0, 99], [0.2, 3, 3, 1.0, 0.0]])
    with pytest.raises(DriveLogError) as info:
        read_drive(path)
    assert_one_line(info, path, ["row 2", "6 fields"])


def test_csv_unparseable_cell(tmp_path):
    header = ["time_s", "left_pulses", "right_pulses", "compass_x", "compass_y", "comment"]
    path = _write_csv_text(tmp_path / "text.csv", header,
                           [[0.0, 1, 1, 1.0, 0.0, "ok"], [0.1, 2, 2, 1.0, 0.0, "fine"], [0.2, "abc", 3, 1.0, 0.0, "x"]])
    with pytest.raises(DriveLogError) as info:
        read_drive(path)
    assert_one_line(info, path, ["row 3", "'left_pulses'", "'abc'"])


@pytest.mark.parametrize("column, cell", [("compass_x", "true"), ("left_pulses", "False"), ("left_pulses", "0x10"),
                                          ("compass_y", " -0X1f")])
def test_csv_booleans_and_hex_are_no_numbers(tmp_path, column, cell):
    """Before stop 44 'true' read 1.0 in any column (a compass sample at (1, 0) used as valid) and Arrow read '0x10'
    as 16.  Booleans stay accepted in the flag columns."""
    header = ["time_s", "left_pulses", "right_pulses", "compass_x", "compass_y", "map_heading_deg", "map_valid"]
    rows = [[0.0, 1, 1, 1.0, 0.0, 10.0, "true"], [0.1, 2, 2, 1.0, 0.0, 10.0, "false"], [0.2, 3, 3, 1.0, 0.0, 10.0, 1]]
    rows[2][header.index(column)] = cell
    path = _write_csv_text(tmp_path / "cells.csv", header, rows)
    with pytest.raises(DriveLogError) as info:
        read_drive(path)
    assert_one_line(info, path, ["row 3", repr(column), repr(cell)])
    rows[2][header.index(column)] = 3 if "pulses" in column else 1.0
    assert read_drive(_write_csv_text(tmp_path / "flags.csv", header, rows)).inputs.map_valid.tolist() == [1, 0, 1]


def test_parquet_boolean_column_where_numbers_belong(tmp_path):
    import pyarrow as pa
    import pyarrow.parquet as pq

    cols = synthetic_columns(n=5)
    table = {k: v for k, v in cols.items()}
    table["compass_x"] = np.asarray(cols["compass_x"]) > 0.0
    path = tmp_path / "bool.parquet"
    pq.write_table(pa.table(table), path)
    with pytest.raises(DriveLogError) as info:
        read_drive(path)
    assert_one_line(info, path, ["'compass_x'", "true/false"])


def test_csv_empty_cells_and_text_columns(tmp_path):
    header = ["time_s", "left_pulses", "right_pulses", "compass_x", "compass_y", "comment"]
    path = _write_csv_text(tmp_path / "cells.csv", header,
                           [[0.0, 1, 1, 1.0, 0.0, "start"], [0.1, 2, 2, "", 0.0, ""], [0.2, 3, 3, " 1.5 ", "NaN", "z"]])
    drive = read_drive(path)
    assert drive.metadata["bad_compass_samples"] == 2
    assert drive.inputs.compass_x[2] == 1.5
    assert drive.metadata["extra_columns"] == ["comment"]
    assert list(read_table(path)["comment"]) == ["start", None, "z"]


def test_csv_empty_pulse_cell_names_row(tmp_path):
    header = ["time_s", "left_pulses", "right_pulses", "compass_x", "compass_y"]
    path = _write_csv_text(tmp_path / "gap.csv", header, [[0.0, 1, 1, 1.0, 0.0], [0.1, 2, "", 1.0, 0.0]])
    with pytest.raises(DriveLogError) as info:
        read_drive(path)
    assert_one_line(info, path, ["row 2", "'right_pulses'"])


def test_csv_header_only_and_duplicate_columns(tmp_path):
    path = tmp_path / "header.csv"
    path.write_text("time_s,left_pulses,right_pulses,compass_x,compass_y\n")
    with pytest.raises(DriveLogError) as info:
        read_drive(path)
    assert_one_line(info, path, ["empty"])
    dup = _write_csv_text(tmp_path / "dup.csv", ["time_s", "time_s", "left_pulses"], [[0, 1, 2]])
    with pytest.raises(DriveLogError) as info:
        read_drive(dup)
    assert_one_line(info, dup, ["'time_s'", "twice"])


def test_mf4_channel_on_another_time_base(tmp_path):
    from asammdf import MDF, Signal

    cols = synthetic_columns(n=10)
    t = cols["time_s"]
    mdf = MDF(version="4.10")
    mdf.append([Signal(cols[k], t, name=k) for k in ("left_pulses", "right_pulses", "compass_x")],
               common_timebase=True)
    mdf.append([Signal(cols["compass_y"][::2], t[::2], name="compass_y")], common_timebase=True)
    path = tmp_path / "groups.mf4"
    mdf.save(path)
    mdf.close()
    with pytest.raises(DriveLogError) as info:
        read_drive(path)
    assert_one_line(info, path, ["'compass_y'", "time base"])


@pytest.mark.parametrize("same_group", [True, False])
def test_mf4_and_parquet_column_twice(tmp_path, same_group):
    """Before stop 44 an MDF4 with two compass_x channels used the first one silently, and a Parquet file's error was
    Arrow's dump of its schema; now both say what a CSV says."""
    import pyarrow as pa
    import pyarrow.parquet as pq
    from asammdf import MDF, Signal

    cols = synthetic_columns(n=10)
    t = cols["time_s"]
    mdf = MDF(version="4.10")
    drive = [Signal(cols[k], t, name=k) for k in ("left_pulses", "right_pulses", "compass_x", "compass_y")]
    other = Signal(np.full(t.size, 99.0), t, name="compass_x")
    mdf.append(drive + [other] if same_group else drive, common_timebase=True)
    if not same_group:
        mdf.append([other], common_timebase=True)
    path = tmp_path / "twice.mf4"
    mdf.save(path)
    mdf.close()
    with pytest.raises(DriveLogError) as info:
        read_drive(path)
    assert_one_line(info, path, ["'compass_x'", "appears twice", "group 0" if same_group else "groups 0 and 1"])

    table = pa.Table.from_arrays([pa.array(cols[k]) for k in cols] + [pa.array(cols["compass_x"])],
                                 names=list(cols) + ["compass_x"])
    parquet = tmp_path / "twice.parquet"
    pq.write_table(table, parquet)
    with pytest.raises(DriveLogError) as info:
        read_drive(parquet)
    assert_one_line(info, parquet, ["'compass_x'", "appears twice"])
    assert "FieldRef" not in str(info.value)


def test_mf4_drive_in_a_later_group(tmp_path):
    """A foreign MDF4: a faster unrelated group first (its master also named time_s), the drive
    in the second group with a master named 'time'."""
    from asammdf import MDF, Signal

    cols = synthetic_columns(n=12)
    fast_t = np.linspace(0.0, 5.0, 37)
    mdf = MDF(version="4.10")
    mdf.append([Signal(np.sin(fast_t), fast_t, name="gyro_z", master_metadata=("time_s", 1))], common_timebase=True)
    mdf.append([Signal(cols[k], cols["time_s"], name=k, master_metadata=("time", 1))
                for k in cols if k != "time_s"], common_timebase=True)
    path = tmp_path / "foreign.mf4"
    mdf.save(path)
    mdf.close()
    drive = read_drive(path)
    assert_same(drive.inputs.time_s, cols["time_s"])
    assert_same(drive.inputs.left_pulses, cols["left_pulses"].astype(np.float64))
    assert "gyro_z" not in drive.metadata["columns"]


def test_mf4_master_channel_is_time_s(tmp_path):
    from asammdf import MDF

    path = write_drive(tmp_path / "d.mf4", synthetic_columns(n=10))
    with MDF(path) as mdf:
        assert len(mdf.groups) == 1
        master = mdf.groups[0].channels[mdf.masters_db[0]]
        assert master.name == "time_s"
        names = [c.name for c in mdf.groups[0].channels]
    assert sorted(names) == sorted(synthetic_columns(n=2))


@pytest.mark.parametrize("content", [b"MDF     4.10    " + b"\xff" * 300, b"MDF     4.10    garbage" * 10],
                         ids=["unfinalised-flags", "garbage"])
def test_a_corrupt_mf4_leaves_nothing_in_the_temporary_folder(tmp_path, monkeypatch, content):
    """asammdf copies an unfinalised MDF 4.10+ file into the temporary folder and deletes the copy only on a
    clean close: a corrupt one left a copy behind on every read (one per test run in /tmp)."""
    import tempfile

    scratch = tmp_path / "tmp"
    scratch.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(scratch))
    path = tmp_path / "corrupt.mf4"
    path.write_bytes(content)
    with pytest.raises(DriveLogError):
        read_drive(path)
    import gc

    gc.collect()
    assert sorted(p.name for p in scratch.iterdir()) == []
    assert path.read_bytes() == content  # the user's file untouched
