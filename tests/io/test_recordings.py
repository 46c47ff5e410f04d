"""Recordings in files: every format written from a simulated run, read back bitwise; the
QUARC multi-file layout with a mapping; one test per bad-recording case (one line naming the
file, the column and the row); bounded inputs (FIFOs, devices, the size limit)."""

from __future__ import annotations

import hashlib
import math
import os
import threading
import time

import numpy as np
import pytest
import scipy.io

from testbed.envs import RigEnv
from testbed.io import formats, readers
from testbed.io.formats import read_recording, write_recording
from testbed.io.mapping import Mapping, load_mapping
from testbed.io.recording import Recording, RecordingError

PITCH_COUNTS, YAW_COUNTS = 4096, 8192
REST_PITCH_DEG = -40.5


@pytest.fixture(scope="module")
def simulated() -> Recording:
    """A helicopter episode (hardware profile: encoders and an IMU), inputs that clip."""
    env = RigEnv("helicopter", profile="hardware")
    _, info = env.reset(seed=11)
    rng = np.random.default_rng(5)
    t, y, u = [info["t"]], [env.sim.obs[0].copy()], []
    for _ in range(300):
        obs, _, _, _, info = env.step(rng.uniform(-30.0, 30.0, 2))
        u.append(info["action_applied"].copy())
        t.append(info["t"])
        y.append(obs)
    env.close()
    y, u = np.array(y[:-1]), np.array(u)
    return Recording(time_s=np.array(t[:-1]),
                     inputs={n: u[:, j] for j, n in enumerate(env.action_names)},
                     channels={n: y[:, j] for j, n in enumerate(env.sensors.names)},
                     meta={"rig": "helicopter", "seed": 11})


def bitwise(a: np.ndarray, b: np.ndarray) -> bool:
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    return a.shape == b.shape and np.array_equal(a.view(np.uint64), b.view(np.uint64))


def same_recording(a: Recording, b: Recording) -> bool:
    return (bitwise(a.time_s, b.time_s) and list(a.inputs) == list(b.inputs)
            and list(a.channels) == list(b.channels)
            and all(bitwise(a.inputs[k], b.inputs[k]) for k in a.inputs)
            and all(bitwise(a.channels[k], b.channels[k]) for k in a.channels))


def one_line(exc: pytest.ExceptionInfo, *parts: str) -> str:
    message = str(exc.value)
    assert "\n" not in message, message
    for part in parts:
        assert part in message, (part, message)
    return message


# ---------------------------------------------------------------------------- round trips
@pytest.mark.parametrize("suffix", [".csv", ".npz", ".mat"])
def test_round_trip_is_bitwise(simulated, tmp_path, suffix):
    assert np.ptp(simulated.inputs["V_yaw"]) == 30.0  # the hardware amplifier clipped
    path = write_recording(tmp_path / f"run{suffix}", simulated)
    back = read_recording(path, rig="helicopter")
    assert same_recording(simulated, back)
    assert back.meta == simulated.meta
    assert back.source == os.fspath(path)
    assert back.sha256 == hashlib.sha256(path.read_bytes()).hexdigest()
    assert not list(tmp_path.glob(".*tmp"))  # written through a temporary, renamed


@pytest.mark.parametrize("suffix", [".csv", ".npz", ".mat"])
def test_round_trip_of_awkward_floats_without_a_rig(tmp_path, suffix):
    special = np.array([0.1 + 0.2, -0.0, 5e-324, 1.7976931348623157e308, -2.2250738585072014e-308,
                        1 / 3, 123456789.123456789, -1e-300])
    rec = Recording(time_s=np.arange(8) * 0.1 + 1e-9, inputs={"u": special[::-1].copy()},
                    channels={"y": special, "z": np.cumsum(special[:1].repeat(8))})
    back = read_recording(write_recording(tmp_path / f"odd{suffix}", rec))
    assert same_recording(rec, back)  # the declaration tells inputs from channels
    assert math.copysign(1.0, back.channels["y"][1]) == -1.0


def test_subset_of_channels_and_independent_writers(simulated, tmp_path):
    t, pitch, v = simulated.time_s, simulated.channels["pitch"], simulated.inputs["V_pitch"]
    csv_path = tmp_path / "subset.csv"
    csv_path.write_text("time_s, pitch ,V_pitch\n" + "".join(
        f"{a!r},{b!r},{c!r}\n" for a, b, c in zip(t.tolist(), pitch.tolist(), v.tolist(),
                                                 strict=True)))
    np.savez(tmp_path / "plain.npz", time_s=t, pitch=pitch, V_pitch=v)
    scipy.io.savemat(tmp_path / "plain.mat", {"time_s": t[None, :], "pitch": pitch[None, :],
                                              "V_pitch": v[:, None]})
    for name in ("subset.csv", "plain.npz", "plain.mat"):
        rec = read_recording(tmp_path / name, rig="helicopter")
        assert list(rec.inputs) == ["V_pitch"] and list(rec.channels) == ["pitch"], name
        assert bitwise(rec.channels["pitch"], pitch) and bitwise(rec.inputs["V_pitch"], v)
        assert bitwise(rec.time_s, t)


def test_sensors_restrict_the_channels(simulated, tmp_path):
    path = write_recording(tmp_path / "run.csv", simulated)
    with pytest.raises(RecordingError) as exc:
        read_recording(path, rig="helicopter", sensors="encoders")
    one_line(exc, str(path), "'gyro_pitch'", "line 2 (the header)",
             "channels [pitch, yaw]", "inputs [V_pitch, V_yaw]")


def test_the_convention_of_a_simulated_run(tmp_path):
    """A run's recording (testbed.experiment.replay.recording_from_result) in a file and back:
    row k holds t_k, what the sensors gave at t_k and the input applied over [t_k, t_k+1)."""
    from testbed.experiment.replay import recording_from_result
    from testbed.experiment.runner import run
    from testbed.experiment.scenario import Scenario

    traj, _ = run(Scenario(rig="helicopter", duration_s=0.5, seed=4))
    rec = recording_from_result(traj)
    assert rec.n_samples == len(traj.t_s) == 51
    assert bitwise(rec.time_s, traj.t_s)
    assert bitwise(rec.inputs["V_pitch"][:-1], traj.action[1:, 0])  # applied over [t_k, t_k+1)
    assert bitwise(rec.channels["yaw"], traj.measurement[:, 1])
    assert "params" not in rec.meta and "params" not in rec.meta["scenario"]  # never the truth
    back = read_recording(write_recording(tmp_path / "run.npz", rec), rig="helicopter")
    assert same_recording(rec, back)


# ---------------------------------------------------------------------------- QUARC layout
def _quarc_experiment(rec: Recording, folder, shift_sample: int | None = None):
    """What a QUARC model's "To File" blocks write: encoder counts (pitch from its rest on the
    stop, yaw counted the other way), the gyro in deg/s, the voltages; row 0 time."""
    folder.mkdir(exist_ok=True)
    t = rec.time_s
    q_pitch, q_yaw = 2 * np.pi / PITCH_COUNTS, 2 * np.pi / YAW_COUNTS
    pitch_counts = (rec.channels["pitch"] - np.deg2rad(REST_PITCH_DEG)) / q_pitch
    yaw_counts = -rec.channels["yaw"] / q_yaw
    t_voltage = t.copy()
    if shift_sample is not None:
        t_voltage[shift_sample] += 0.05 * rec.dt_s
    scipy.io.savemat(folder / "encoders.mat", {"enc": np.vstack([t, pitch_counts, yaw_counts])})
    scipy.io.savemat(folder / "voltage.mat",
                     {"volts": np.vstack([t_voltage, rec.inputs["V_yaw"], rec.inputs["V_pitch"]])})
    scipy.io.savemat(folder / "gyro.mat", {"gyro": np.vstack(
        [t, np.rad2deg(rec.channels["gyro_pitch"])]), "note": np.arange(3.0)})
    mapping = folder / "quarc.toml"
    mapping.write_text(f"""
[columns.pitch]
file = "encoders.mat"
row = 1
unit = "counts"
counts_per_rev = {PITCH_COUNTS}
offset = {REST_PITCH_DEG}
offset_unit = "deg"

[columns.yaw]
file = "encoders.mat"
row = 2
unit = "counts"
counts_per_rev = {YAW_COUNTS}
sign = -1

[columns.V_pitch]
file = "voltage.mat"
row = 2
unit = "V"

[columns.V_yaw]
file = "voltage.mat"
row = 1

[columns.gyro_pitch]
file = "gyro.mat"
variable = "gyro"
row = 1
unit = "deg/s"
""")
    return mapping


def test_quarc_files_with_a_mapping(simulated, tmp_path):
    folder = tmp_path / "experiment"
    mapping = _quarc_experiment(simulated, folder)
    files = [folder / "voltage.mat", folder / "gyro.mat", folder / "encoders.mat"]
    from_dir = read_recording(folder, mapping=mapping, rig="helicopter")
    from_list = read_recording(files, mapping=load_mapping(mapping), rig="helicopter")
    for rec in (from_dir, from_list):
        assert list(rec.inputs) == ["V_pitch", "V_yaw"]
        assert list(rec.channels) == ["pitch", "yaw", "gyro_pitch"]
        for name in rec.channels:  # counts, degrees, sign and offset undone
            np.testing.assert_allclose(rec.channels[name], simulated.channels[name], rtol=0,
                                       atol=1e-12)
        assert bitwise(rec.inputs["V_pitch"], simulated.inputs["V_pitch"])
        assert bitwise(rec.time_s, simulated.time_s)
    digests = {f.name: hashlib.sha256(f.read_bytes()).digest() for f in files}
    expected = hashlib.sha256(b"".join(digests[k] for k in sorted(digests))).hexdigest()
    assert from_dir.sha256 == from_list.sha256 == expected
    assert sorted(os.path.basename(f) for f in from_dir.meta["files"]) == sorted(digests)
    assert from_dir.meta["mapping"]["sha256"] == hashlib.sha256(mapping.read_bytes()).hexdigest()


def test_quarc_times_must_agree(simulated, tmp_path):
    folder = tmp_path / "experiment"
    mapping = _quarc_experiment(simulated, folder, shift_sample=17)
    with pytest.raises(RecordingError) as exc:
        read_recording(folder, mapping=mapping)
    one_line(exc, str(folder / "voltage.mat"), "row 0 (time)", "sample 17", "1%")


def test_quarc_row_and_file_errors(simulated, tmp_path):
    folder = tmp_path / "experiment"
    mapping = _quarc_experiment(simulated, folder)
    mapping.write_text(mapping.read_text().replace("row = 2\nunit = \"V\"", "row = 5"))
    with pytest.raises(RecordingError) as exc:
        read_recording(folder, mapping=mapping)
    one_line(exc, "voltage.mat", "rows 0..2", "[columns.V_pitch] reads row 5")
    with pytest.raises(RecordingError) as exc:
        read_recording([folder / "gyro.mat"], mapping=mapping)
    one_line(exc, "encoders.mat", "is not among the files read")
    with pytest.raises(RecordingError) as exc:  # a QUARC array without a mapping
        read_recording(folder / "encoders.mat")
    one_line(exc, "encoders.mat", "'enc'", "3 x 300", "mapping")


# ---------------------------------------------------------------------------- mappings
def test_csv_mapping_degrees_sign_offset_segment(simulated, tmp_path):
    t = simulated.time_s
    pitch_deg = np.rad2deg(simulated.channels["pitch"])
    table = np.column_stack([t * 1000.0, -pitch_deg, simulated.inputs["V_yaw"], t])
    path = tmp_path / "log.csv"
    path.write_text("t_ms,Pitch (deg),Vy,temperature\n" + "".join(
        ",".join(repr(v) for v in row) + "\n" for row in table.tolist()))
    (tmp_path / "m.toml").write_text("""
time = "t_ms"
time_unit = "ms"
start_s = 0.5
stop_s = 2.0
ignore = ["temperature"]
[columns.pitch]
from = "Pitch (deg)"
unit = "deg"
sign = -1
offset = 0.25
[columns.V_yaw]
from = "Vy"
""")
    rec = read_recording(path, mapping=tmp_path / "m.toml", rig="helicopter")
    keep = (t * 1000.0 * 1e-3 >= 0.5) & (t * 1000.0 * 1e-3 <= 2.0)
    assert rec.n_samples == keep.sum() == 151
    np.testing.assert_allclose(rec.time_s, t[keep], rtol=0, atol=1e-15)
    np.testing.assert_allclose(rec.channels["pitch"], simulated.channels["pitch"][keep] + 0.25,
                               rtol=0, atol=1e-14)
    assert bitwise(rec.inputs["V_yaw"], simulated.inputs["V_yaw"][keep])


@pytest.mark.parametrize("text, expected", [
    ("colour = 1", "unknown key 'colour'"),
    ("[columns.pitch]\nunit = \"counts\"", "counts_per_rev"),
    ("[columns.pitch]\nsign = 2", "sign must be 1 or -1"),
    ("[columns.pitch]\nunit = \"furlong\"", "not a known unit"),
    ("[columns.pitch]\nfile = \"../x.mat\"\nrow = 1", "without '..'"),
    ("start_s = 3\nstop_s = 1", "start_s (3) must be before stop_s (1)"),
    ("[columns.pitch\n", "not a TOML file"),
])
def test_bad_mappings(tmp_path, text, expected):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(RecordingError) as exc:
        load_mapping(path)
    one_line(exc, str(path), expected)


def test_mapping_unit_must_fit_the_rig(simulated, tmp_path):
    path = write_recording(tmp_path / "run.csv", simulated)
    mapping = Mapping.from_dict({"columns": {"pitch": {"unit": "deg/s"}}}, source="m.toml")
    with pytest.raises(RecordingError) as exc:
        read_recording(path, mapping=mapping, rig="helicopter")
    one_line(exc, str(path), "'pitch'", "gives rad/s", "in rad")


# ---------------------------------------------------------------------------- bad recordings
GOOD = ["time_s,V_pitch,pitch", *(f"{0.01 * k:.2f},1.5,{0.001 * k}" for k in range(8))]


def _bad_csv(tmp_path, line: int | None, text: str | None, lines=None):
    rows = list(GOOD if lines is None else lines)
    if line is not None:
        rows[line - 1] = text
    path = tmp_path / "bad.csv"
    path.write_text("\n".join(rows) + "\n")
    return path


@pytest.mark.parametrize("line, text, column, expected", [
    (6, "0.02,1.5,0.004", "time_s", "time 0.02 s goes back (after 0.03 s)"),
    (4, "nan,1.5,0.002", "time_s", "time nan is not finite"),
    (5, "0.02,1.5,0.003", "time_s", "time 0.02 s repeats"),
    (4, "0.02,1.5,nan", "pitch", "NaN (a gap)"),
    (4, "0.02,,0.002", "V_pitch", "empty cell"),
    (7, "0.05,1.5,abc", "pitch", "not a number: 'abc'"),
    (3, "0.01,1.5", "pitch", "2 cells, the header has 3"),
    (5, "", "time_s", "empty row"),
    (8, "0.0602,1.5,0.006", "time_s", "uniform within 1% of the median step"),
    (1, "time_s,V_pitch,pitch_deg", "pitch_deg", "not an input or sensor channel"),
], ids=["decreasing-time", "nan-time", "duplicate-time", "nan-gap", "empty-cell",
        "not-a-number", "short-row", "empty-row", "rate-not-uniform", "unknown-channel"])
def test_bad_csv_is_one_line_naming_file_column_row(tmp_path, line, text, column, expected):
    path = _bad_csv(tmp_path, line, text)
    with pytest.raises(RecordingError) as exc:
        read_recording(path, rig="helicopter")
    row = "line 1 (the header)" if line == 1 else f"line {line}"
    one_line(exc, str(path), f"column {column!r}", row, expected)


def test_unknown_channel_lists_the_valid_names(tmp_path):
    path = _bad_csv(tmp_path, 1, "time_s,V_pitch,pitch_deg")
    with pytest.raises(RecordingError) as exc:
        read_recording(path, rig="helicopter")
    one_line(exc, "inputs [V_pitch, V_yaw]", "gyro_pitch", "accel_x", "pitch_rate")


def test_jitter_below_the_tolerance_is_accepted(tmp_path):
    rng = np.random.default_rng(1)
    t = 0.01 * np.arange(500) + rng.uniform(-0.004, 0.004, 500) * 0.01  # steps within 0.8 %
    path = tmp_path / "jitter.csv"
    path.write_text("time_s,pitch\n" + "".join(f"{v!r},0.0\n" for v in t.tolist()))
    assert read_recording(path, rig="helicopter").n_samples == 500
    t[250] += 0.0015  # one step 15 % long: refused at its sample
    path.write_text("time_s,pitch\n" + "".join(f"{v!r},0.0\n" for v in t.tolist()))
    with pytest.raises(RecordingError) as exc:
        read_recording(path)
    one_line(exc, "column 'time_s'", "line 252", "1%")


def test_missing_time_column(tmp_path):
    path = _bad_csv(tmp_path, 1, "t,V_pitch,pitch")
    with pytest.raises(RecordingError) as exc:
        read_recording(path)
    one_line(exc, str(path), "column 'time_s' missing", "line 1", "t, V_pitch, pitch")


def test_empty_file(tmp_path):
    path = tmp_path / "empty.csv"
    path.write_bytes(b"")
    with pytest.raises(RecordingError) as exc:
        read_recording(path)
    one_line(exc, str(path), "empty file")
    path.write_text("# only a comment\n\n")
    with pytest.raises(RecordingError) as exc:
        read_recording(path)
    one_line(exc, str(path), "empty file")


@pytest.mark.parametrize("samples", [0, 1])
def test_fewer_than_two_samples(tmp_path, samples):
    path = _bad_csv(tmp_path, None, None, lines=GOOD[:1 + samples])
    with pytest.raises(RecordingError) as exc:
        read_recording(path)
    one_line(exc, str(path), "column 'time_s'", f"{samples} sample", "at least 2")


def test_bad_arrays_name_the_sample(tmp_path):
    t = 0.01 * np.arange(10)
    y = np.zeros(10)
    y[6] = np.nan
    np.savez(tmp_path / "gap.npz", time_s=t, pitch=y)
    with pytest.raises(RecordingError) as exc:
        read_recording(tmp_path / "gap.npz")
    one_line(exc, str(tmp_path / "gap.npz"), "column 'pitch'", "sample 6", "NaN")
    np.savez(tmp_path / "text.npz", time_s=t, pitch=np.array(["a"] * 10))
    with pytest.raises(RecordingError) as exc:
        read_recording(tmp_path / "text.npz")
    one_line(exc, "text.npz", "column 'pitch'", "not a number (text)")
    scipy.io.savemat(tmp_path / "short.mat", {"time_s": t, "pitch": y[:7]})
    with pytest.raises(RecordingError) as exc:
        read_recording(tmp_path / "short.mat")
    one_line(exc, "short.mat", "column 'pitch'", "sample 7", "7 samples, 'time_s' has 10")


def test_matlab_v73_is_refused_in_one_line(tmp_path):
    import importlib.util

    if importlib.util.find_spec("h5py"):
        pytest.skip("h5py installed: v7.3 files are read")
    header = b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: Tue Dec  1 2026 HDF5 schema"
    path = tmp_path / "new.mat"
    path.write_bytes(header.ljust(512, b" ") + b"\x89HDF\r\n\x1a\n" + bytes(64))
    with pytest.raises(RecordingError) as exc:
        read_recording(path)
    one_line(exc, str(path), "v7.3 (HDF5)", "save it as v5", "h5py")


# ---------------------------------------------------------------------------- bounded inputs
def _quickly(fn, seconds: float = 5.0):
    """``fn()``'s exception, raised within ``seconds`` (a blocking read would hang)."""
    box: dict = {}

    def target():
        try:
            fn()
        except BaseException as exc:  # noqa: BLE001 - handed to the test
            box["exc"] = exc

    start = time.perf_counter()
    thread = threading.Thread(target=target, daemon=True)
    thread.start()
    thread.join(seconds)
    assert not thread.is_alive(), "the read blocked"
    return box.get("exc"), time.perf_counter() - start


def test_fifo_is_refused_without_blocking(tmp_path):
    fifo = tmp_path / "pipe.csv"
    os.mkfifo(fifo)
    exc, took = _quickly(lambda: read_recording(fifo))
    assert isinstance(exc, RecordingError) and "a FIFO" in str(exc) and str(fifo) in str(exc)
    exc, _ = _quickly(lambda: formats.read_bounded(fifo))  # the descriptor check itself
    assert isinstance(exc, RecordingError) and "a FIFO" in str(exc)
    assert took < 1.0


def test_devices_are_refused(tmp_path):
    link = tmp_path / "zero.csv"
    link.symlink_to("/dev/zero")
    for path in ("/dev/zero", link):
        exc, took = _quickly(lambda p=path: read_recording(p))
        assert isinstance(exc, RecordingError) and "character device" in str(exc), exc
        assert took < 1.0
    exc, _ = _quickly(lambda: formats.read_bounded("/dev/zero"))
    assert isinstance(exc, RecordingError) and "character device" in str(exc)


def test_size_limit_checked_before_reading(tmp_path, monkeypatch):
    big = tmp_path / "big.csv"
    with open(big, "wb") as f:  # sparse: 3 GiB of holes, no disk used
        f.truncate(3 << 30)
    start = time.perf_counter()
    with pytest.raises(RecordingError) as exc:
        read_recording(big)
    assert time.perf_counter() - start < 1.0
    one_line(exc, str(big), f"{3 << 30} bytes", "larger than 2,147,483,648 bytes")
    small = _bad_csv(tmp_path, None, None)
    monkeypatch.setattr(readers, "MAX_RECORDING_BYTES", 64)  # (where it is read)
    with pytest.raises(RecordingError) as exc:
        read_recording(small)
    one_line(exc, str(small), "larger than 64 bytes")


def test_writer_refuses_bad_recordings_and_names(tmp_path):
    t = np.arange(4) * 0.1
    with pytest.raises(RecordingError, match="column 'y', sample 2: NaN"):
        write_recording(tmp_path / "a.csv", Recording(t, {}, {"y": np.array([0, 1, np.nan, 2])}))
    with pytest.raises(RecordingError, match="cannot be written to a .mat file"):
        write_recording(tmp_path / "a.mat", Recording(t, {}, {"y-z": np.zeros(4)}))
    with pytest.raises(ValueError, match="must end in .csv, .npz, .mat"):
        write_recording(tmp_path / "a.txt", Recording(t, {}, {"y": np.zeros(4)}))
    assert not list(tmp_path.iterdir())


def test_mapping_kinds_without_a_rig_and_path_errors(tmp_path):
    t = 0.02 * np.arange(20)
    np.savez(tmp_path / "log.npz", time_s=t, volts=np.full(20, 2.0), ang=np.linspace(0, 90, 20))
    mapping = Mapping.from_dict({"columns": {
        "V_pitch": {"from": "volts", "kind": "input", "unit": "mV", "scale": 2.0},
        "pitch": {"from": "ang", "unit": "deg"}}}, source="m.toml")
    rec = read_recording(tmp_path / "log.npz", mapping=mapping)
    assert list(rec.inputs) == ["V_pitch"] and list(rec.channels) == ["pitch"]
    np.testing.assert_allclose(rec.inputs["V_pitch"], 4e-3, rtol=1e-15)
    np.testing.assert_allclose(rec.channels["pitch"][-1], np.pi / 2, rtol=1e-15)
    missing = Mapping.from_dict({"columns": {"pitch": {"from": "theta"}}}, source="m.toml")
    with pytest.raises(RecordingError) as exc:
        read_recording(tmp_path / "log.npz", mapping=missing)
    one_line(exc, "m.toml", "[columns.pitch] reads column 'theta'", "ang, volts")
    for path, expected in ((tmp_path, "a directory"), (tmp_path / "log.txt", "unknown recording "
                           "format '.txt'"), (tmp_path / "none.csv", "no such recording file")):
        if expected.startswith("unknown"):
            path.write_text("time_s\n")
        with pytest.raises(RecordingError) as exc:
            read_recording(path)
        one_line(exc, str(path), expected)


def test_matlab_v73_read_with_h5py_when_installed(tmp_path):
    h5py = pytest.importorskip("h5py")
    path = tmp_path / "new.mat"
    t = 0.01 * np.arange(50)
    with h5py.File(path, "w", userblock_size=512) as f:
        f["time_s"] = t[None, :]  # what MATLAB writes for a column vector (transposed)
        f["pitch"] = np.sin(t)[None, :]
    with open(path, "r+b") as f:
        f.write(b"MATLAB 7.3 MAT-file, Platform: GLNXA64, HDF5 schema 1.00 .".ljust(128))
    rec = read_recording(path)
    assert bitwise(rec.time_s, t) and bitwise(rec.channels["pitch"], np.sin(t))
