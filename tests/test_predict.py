"""`fftool predict` and the Python API: the same futures as `evaluate` for the same windows, seed and model
(real zara1), one-line errors for bad files, and never overwriting a user's file."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from fftool import pipeline
from fftool.api import load, predict_tracks
from fftool.artifacts.schema import PREDICTIONS_FILE
from fftool.artifacts.store import ArtifactStore
from fftool.cli import app
from fftool.config import load_config, predictor_config
from fftool.dataset.trackfiles import read_tracks
from fftool.errors import RawDataError
from fftool.learning.batches import load_agent_windows
from fftool.models.forceformer import Gaussian

from .conftest import REAL_RAW, TINY_CVAE


def _train(raw: Path, root: Path, variant: str, protocol: str = "paper") -> dict:
    cfg = load_config(None, [f"data.raw_dir={str(raw)!r}", *TINY_CVAE, f"evaluate.protocol={protocol!r}"])
    return pipeline.run(predictor_config(cfg, variant), ArtifactStore(root), ["evaluate"], benchmark="zara1")


def _observed_file(built: dict, path: Path) -> tuple[Path, np.ndarray]:
    """The zara1 test part's observed steps as a user file: one track per agent-window (id = window, ped),
    so the agents with 8 observed steps at each time are exactly that window's; returns the true end points."""
    data = load_agent_windows(built["windows"], "zara1", "test")
    frames = (data.first_step[:, None] + np.arange(8)) * 10
    agent = data.window_id * 100_000 + data.ped_id
    obs = data.xy[:, :8]
    table = {"frame": frames.reshape(-1), "agent_id": np.repeat(agent, 8), "x": obs[..., 0].reshape(-1)}
    pd.DataFrame(table | {"y": obs[..., 1].reshape(-1)}).to_csv(path, index=False)
    return path, np.column_stack([agent, data.xy[:, -1]])


def _evaluated(built: dict) -> np.ndarray:
    frame = pd.read_parquet(built["evaluate"].file(PREDICTIONS_FILE))
    return np.stack(frame["pred"].to_numpy()).reshape(len(frame), 20, 12, 2)


def _predicted(out: Path, n: int) -> np.ndarray:
    frame = pd.read_parquet(out).sort_values(["time_s", "agent", "sample", "step"], kind="stable")
    return frame[["x", "y"]].to_numpy().reshape(n, 20, 12, 2)


@pytest.mark.slow
@pytest.mark.data
def test_predict_on_real_zara1_gives_evaluates_numbers(tmp_path: Path) -> None:
    if not REAL_RAW.is_dir():
        pytest.skip("real data absent")
    root = tmp_path / "artifacts"
    built = _train(REAL_RAW.resolve(), root, "baseline")
    tracks, ends = _observed_file(built, tmp_path / "zara1_test.csv")
    out = tmp_path / "futures.parquet"
    args = ["predict", str(tracks), "--model", built["cvae"].id, "--root", str(root), "--at", "all", "--out", str(out)]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.output
    expected = _evaluated(built)
    assert np.array_equal(_predicted(out, len(expected)), expected)  # the same numbers, not close ones

    # A goal variant with the true end points as given goals = evaluate's oracle protocol.
    built = _train(REAL_RAW.resolve(), root, "dr", "oracle")
    goals = tmp_path / "goals.csv"
    pd.DataFrame({"agent_id": ends[:, 0].astype(np.int64), "x": ends[:, 1], "y": ends[:, 2]}).to_csv(goals, index=False)
    out = tmp_path / "dr.parquet"
    args = ["predict", str(tracks), "--model", built["cvae"].id, "--root", str(root), "--at", "all"]
    result = CliRunner().invoke(app, [*args, "--goals", str(goals), "--out", str(out)])
    assert result.exit_code == 0, result.output
    expected = _evaluated(built)
    assert np.array_equal(_predicted(out, len(expected)), expected)


@pytest.fixture
def tiny_model(tiny_cvaes: dict[str, object]) -> tuple[Path, str]:
    """The shared tiny baseline CVAE (conftest.tiny_cvaes): its store and id."""
    return tiny_cvaes["root"], tiny_cvaes["baseline"]


def _walkers(path: Path, n_steps: int = 10, **columns: object) -> Path:
    step = np.arange(n_steps)
    rows = {"time": np.r_[step, step] * 0.4, "agent_id": np.repeat([1, 2], n_steps)}
    rows |= {"x": np.r_[step * 0.5, step * 0.4], "y": np.r_[step * 0.0, 2.0 + step * 0.1]}
    pd.DataFrame(rows | columns).to_csv(path, index=False)
    return path


def test_predict_writes_k_futures_per_agent_and_the_api_agrees(tiny_model: tuple[Path, str], tmp_path: Path) -> None:
    root, model_id = tiny_model
    tracks, out = _walkers(tmp_path / "t.csv"), tmp_path / "f.parquet"
    args = ["predict", str(tracks), "--model", model_id, "--root", str(root), "--k", "5", "--out", str(out)]
    result = CliRunner().invoke(app, [*args, "--plot", str(tmp_path / "f.png")])
    assert result.exit_code == 0, result.output
    table = pd.read_parquet(out)
    assert set(table.columns) == {"time_s", "agent", "sample", "step", "x", "y", "goal_x", "goal_y"}
    assert len(table) == 2 * 5 * 12 and (tmp_path / "f.png").is_file()
    assert CliRunner().invoke(app, args).exit_code == 0  # its own previous output may be replaced
    model = load(model_id, root=root)
    past = read_tracks(tracks)[["x", "y"]].to_numpy().reshape(1, 2, 10, 2)[:, :, -8:]
    futures = model.predict(past, np.ones((1, 2), bool), k=5)
    assert futures.shape == (1, 5, 2, 12, 2)
    same, _ = predict_tracks(model, read_tracks(tracks), k=5)
    assert np.array_equal(same[["x", "y"]].to_numpy().reshape(2, 5, 12, 2), futures[0].transpose(1, 0, 2, 3))


def test_the_most_likely_future_is_the_prior_means_decoding(
    tiny_model: tuple[Path, str], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """`Model.most_likely` and `predict --most-likely` give one deterministic future per agent: what sampling
    gives when every draw is the prior's mean (checked through the sampling path itself)."""
    root, model_id = tiny_model
    model, tracks = load(model_id, root=root), _walkers(tmp_path / "t.csv")
    past = read_tracks(tracks)[["x", "y"]].to_numpy().reshape(1, 2, 10, 2)[:, :, -8:]
    mask = np.ones((1, 2), bool)
    path = model.most_likely(past, mask)
    assert path.shape == (1, 2, 12, 2) and np.array_equal(path, model.most_likely(past, mask))
    assert not np.allclose(model.predict(past, mask, k=1)[:, 0], path, atol=1e-4)  # a draw is not the centre
    monkeypatch.setattr(Gaussian, "sample", lambda self, generator=None, noise=None: self.mu)
    assert np.allclose(model.predict(past, mask, k=1)[:, 0], path, atol=1e-5)
    out = tmp_path / "path.parquet"
    args = ["predict", str(tracks), "--model", model_id, "--root", str(root), "--most-likely", "--out", str(out)]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.output
    table = pd.read_parquet(out).sort_values(["agent", "step"])
    assert len(table) == 2 * 12 and set(table["sample"]) == {0}
    assert np.allclose(table[["x", "y"]].to_numpy().reshape(2, 12, 2), path[0], atol=1e-5)


def test_tracks_at_another_rate_are_resampled_with_a_warning(tiny_model: tuple[Path, str], tmp_path: Path) -> None:
    root, model_id = tiny_model
    step = np.arange(40)
    tracks = tmp_path / "fast.csv"
    pd.DataFrame({"t": step * 0.1, "id": 7, "x": step * 0.1, "y": 0.0}).to_csv(tracks, index=False)  # 10 Hz
    args = ["predict", str(tracks), "--model", model_id, "--root", str(root), "--out", str(tmp_path / "o.parquet")]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.output
    assert "the other 30 lie between its points and were not used" in result.output  # every 4th sample is on it
    pd.DataFrame({"t": step * 0.3, "id": 7, "x": step * 0.3, "y": 0.0}).to_csv(tracks, index=False)  # 0.3 s
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.output
    assert "by linear interpolation onto the model's 0.4 s step" in result.output


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"drop": "y"}, "no y column"),
        ({"x": ["1.0"] * 19 + ["abc"]}, "line 21, column 'x': expected a finite number, found 'abc'"),
        ({"steps": 5}, "no agent has 8 observed steps"),
        ({"cm_after": 15}, "positions must all be in one unit"),
        ({"gap": True}, "has no position from time"),
    ],
)
def test_bad_files_are_one_line_errors(
    tiny_model: tuple[Path, str], tmp_path: Path, change: dict, message: str
) -> None:
    root, model_id = tiny_model
    tracks = _walkers(tmp_path / "bad.csv", n_steps=change.get("steps", 10))
    frame = pd.read_csv(tracks, dtype=str)
    if "drop" in change:
        frame = frame.drop(columns=change["drop"])
    if "x" in change:
        frame["x"] = change["x"]
    if "cm_after" in change:  # the second half of a track in centimetres
        rows = frame.index[change["cm_after"] :]
        frame.loc[rows, "x"] = (frame.loc[rows, "x"].astype(float) * 100).astype(str)
    if "gap" in change:
        frame = frame.drop(index=[3, 4, 5])
    frame.to_csv(tracks, index=False)
    out = tmp_path / "o.parquet"
    result = CliRunner().invoke(
        app, ["predict", str(tracks), "--model", model_id, "--root", str(root), "--out", str(out)]
    )
    assert result.exit_code == 1, result.output
    assert result.output.startswith("Error: ") and result.output.count("\n") == 1, result.output
    assert str(tracks) in result.output and message in result.output
    assert not out.exists()


def test_a_users_file_is_never_overwritten(tiny_model: tuple[Path, str], tmp_path: Path) -> None:
    root, model_id = tiny_model
    tracks = _walkers(tmp_path / "t.csv")
    mine = tmp_path / "mine.parquet"
    pd.DataFrame({"a": [1]}).to_parquet(mine)
    before = mine.read_bytes()
    result = CliRunner().invoke(
        app, ["predict", str(tracks), "--model", model_id, "--root", str(root), "--out", str(mine)]
    )
    assert result.exit_code == 2 and "refusing to overwrite" in result.output
    assert mine.read_bytes() == before


def test_units_and_frame_columns(tmp_path: Path) -> None:
    path = tmp_path / "mm.csv"
    pd.DataFrame({"frame_id": [0, 10, 20], "ped_id": [3, 3, 3], "x": [0, 400, 800], "y": [0, 0, 0]}).to_csv(path)
    tracks = read_tracks(path, units="mm", frame_step_s=0.4)
    assert np.allclose(tracks["x"], [0, 0.4, 0.8]) and np.allclose(tracks["time_s"], [0, 0.4, 0.8])
    with pytest.raises(RawDataError, match="unknown unit 'ft'"):
        read_tracks(path, units="ft")


def test_the_api_refuses_a_model_of_another_schema_version(tiny_model: tuple[Path, str], tmp_path: Path) -> None:
    """api.load checks the manifest's schema version against the one this fftool reads (it once compared the
    manifest's version with itself), and names the command that rebuilds it."""
    import json
    import shutil

    from fftool.artifacts.hashing import fingerprint
    from fftool.errors import SchemaError

    root, model_id = tiny_model
    store = ArtifactStore(root)
    data = json.loads((store.resolve(model_id).path / "manifest.json").read_text())
    newer = data["schema_version"] + 1  # a model of a newer fftool: its fingerprint hashes its own version
    fp = fingerprint("cvae", newer, data["params"], data["inputs"])
    folder = tmp_path / "store" / "cvae" / fp[:16]
    shutil.copytree(store.resolve(model_id).path, folder)
    (folder / "manifest.json").write_text(json.dumps(data | {"schema_version": newer, "fingerprint": fp}))
    with pytest.raises(SchemaError, match="fftool train-cvae --force"):
        load(folder)
    assert load(store.resolve(model_id).path).variant == "baseline"  # the untouched folder loads


def test_the_api_refuses_input_a_model_cannot_take_and_padding_never_spoils_real_agents(
    tiny_model: tuple[Path, str],
) -> None:
    """NaN or inf or 1e30 in a real agent's past, a window without agents, k = 0, True or an enormous k: one
    InputError naming where, before any work; NaN in a padded slot changes nothing for the real agents."""
    from fftool.errors import InputError

    root, model_id = tiny_model
    model = load(model_id, root=root)
    past = np.cumsum(np.full((2, 3, 8, 2), 0.4), axis=2)
    past[:, 1] += 3.0
    mask = np.array([[True, True, False], [True, False, False]])
    clean = model.predict(past, mask, k=4, seed=1)
    assert np.isfinite(clean[:, :, :2][np.broadcast_to(mask[:, None, :2, None, None], clean[:, :, :2].shape)]).all()
    spoiled = past.copy()
    spoiled[0, 2] = np.nan  # a padded slot full of NaN
    spoiled[1, 1:] = np.inf
    again = model.predict(spoiled, mask, k=4, seed=1)
    real = np.broadcast_to(mask[:, None, :, None, None], clean.shape)
    assert np.array_equal(again[real], clean[real]) and np.isfinite(again[real]).all()
    for value in (np.nan, np.inf, 1e30):
        bad = past.copy()
        bad[1, 0, 5, 1] = value
        with pytest.raises(InputError, match=r"window 1, agent 0, observed step 5"):
            model.predict(bad, mask, k=4)
    with pytest.raises(InputError, match="window 1: agent_mask marks no agent"):
        model.predict(past, np.array([[True, False, False], [False, False, False]]), k=4)
    for k in (0, -3, True, 2.5):
        with pytest.raises(InputError, match="expected a whole number of samples"):
            model.predict(past, mask, k=k)  # type: ignore[arg-type]
    with pytest.raises(InputError, match="lower k"):
        model.predict(past, mask, k=10**9)
    from fftool.errors import UsageError

    with pytest.raises(UsageError, match="device 'tpu'"):
        load(model_id, root=root, device="tpu")


def test_predict_refuses_a_non_finite_time_and_an_enormous_k_before_the_work(
    tiny_model: tuple[Path, str], tmp_path: Path
) -> None:
    root, model_id = tiny_model
    tracks = _walkers(tmp_path / "t.csv")
    common = ["predict", str(tracks), "--model", model_id, "--root", str(root), "--out", str(tmp_path / "f.parquet")]
    nan = CliRunner().invoke(app, [*common, "--at", "nan"])
    assert nan.exit_code == 2 and "expected finite times" in nan.output
    huge = CliRunner().invoke(app, [*common, "--k", str(10**9)])
    assert huge.exit_code == 1 and "lower k" in huge.output and len(huge.output.strip().splitlines()) == 1
    assert not (tmp_path / "f.parquet").exists()


def test_an_empty_track_file_is_one_clear_error(tmp_path: Path) -> None:
    """A 0-byte CSV once ended in 'unexpected Error: Could not determine delimiter'."""
    from fftool.dataset.trackfiles import Columns, read_tracks
    from fftool.errors import RawDataError

    empty = tmp_path / "tracks.csv"
    empty.write_bytes(b"")
    with pytest.raises(RawDataError, match=r"tracks\.csv: empty file: expected a table with a header line"):
        read_tracks(empty, Columns(), "m", None, frame_step_s=0.4)


def test_predict_never_replaces_a_symlink_given_as_out(tiny_model: tuple[Path, str], tmp_path: Path) -> None:
    """--out as a link to fftool's own prediction file once replaced the link with a file."""
    root, model_id = tiny_model
    tracks, own = _walkers(tmp_path / "t.csv"), tmp_path / "own.parquet"
    common = ["predict", str(tracks), "--model", model_id, "--root", str(root), "--k", "2"]
    assert CliRunner().invoke(app, [*common, "--out", str(own)]).exit_code == 0
    link = tmp_path / "link.parquet"
    link.symlink_to(own)
    result = CliRunner().invoke(app, [*common, "--out", str(link)])
    assert result.exit_code == 2 and "a symbolic link" in result.output
    assert link.is_symlink() and link.resolve() == own.resolve()


def test_predict_and_the_api_refuse_a_damaged_or_swapped_model_file(
    tiny_model: tuple[Path, str], tmp_path: Path
) -> None:
    """One flipped bit in model.pt gave all-NaN futures with exit 0, and another model's model.pt copied into
    the folder was loaded silently: every load now checks the files against the manifest first."""
    import shutil

    from fftool.errors import IntegrityError

    root, model_id = tiny_model
    original = ArtifactStore(root).resolve(model_id)
    copy_root = tmp_path / "store"
    folder = copy_root / "cvae" / original.path.name
    shutil.copytree(original.path, folder)
    for chain_kind in ("windows",):  # the model's windows artifact, for the API's window layout
        for up in (root / chain_kind).iterdir():
            shutil.copytree(up, copy_root / chain_kind / up.name)
    weights = bytearray((folder / "model.pt").read_bytes())
    weights[len(weights) // 2] ^= 0x01  # one bit
    (folder / "model.pt").write_bytes(bytes(weights))
    tracks = _walkers(tmp_path / "t.csv")
    args = ["predict", str(tracks), "--model", model_id, "--root", str(copy_root), "--out", str(tmp_path / "o.parquet")]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 1 and "model.pt: content changed" in result.output
    assert len(result.output.strip().splitlines()) == 1 and not (tmp_path / "o.parquet").exists()
    with pytest.raises(IntegrityError, match=r"model\.pt: content changed"):
        load(folder)


def test_generated_api_input_gives_finite_futures_or_one_clear_error(tiny_model: tuple[Path, str]) -> None:
    """Hypothesis draws windows, masks, coordinates (NaN, inf, huge included) and k: the API returns finite
    futures for the real agents or raises InputError / UsageError, never a traceback or NaN out of finite input."""
    from hypothesis import HealthCheck, given, settings
    from hypothesis import strategies as st
    from hypothesis.extra.numpy import arrays

    from fftool.errors import InputError, UsageError

    root, model_id = tiny_model
    model = load(model_id, root=root)
    coordinate = st.one_of(st.floats(-30, 30), st.sampled_from([np.nan, np.inf, -np.inf, 1e30, 0.0]))

    from tests.test_track_files import FUZZ_EXAMPLES

    @settings(max_examples=FUZZ_EXAMPLES, deadline=None, suppress_health_check=list(HealthCheck))
    @given(
        past=st.integers(1, 3).flatmap(
            lambda b: st.integers(1, 4).flatmap(lambda a: arrays(np.float64, (b, a, 8, 2), elements=coordinate))
        ),
        data=st.data(),
        k=st.one_of(st.integers(-1, 6), st.just(True), st.floats(0.5, 3)),
    )
    def check(past: np.ndarray, data: st.DataObject, k: object) -> None:
        mask = data.draw(arrays(np.bool_, past.shape[:2]))
        try:
            futures = model.predict(past, mask, k=k)  # type: ignore[arg-type]
        except (InputError, UsageError) as exc:
            assert "\n" not in str(exc)
            return
        assert futures.shape == (past.shape[0], k, past.shape[1], 12, 2)
        assert np.isfinite(futures[np.broadcast_to(mask[:, None, :, None, None], futures.shape)]).all()

    check()


def test_generated_track_files_and_options_give_a_forecast_or_one_error_line(
    tiny_model: tuple[Path, str], tmp_path_factory: pytest.TempPathFactory
) -> None:
    """`fftool predict`'s door: Hypothesis writes track files (odd numbers, text, missing or extra columns,
    duplicated rows, a byte-order mark, thousands of metres) and picks --k, --at and --seed. Every run ends in a
    Parquet of finite futures with exit 0, or one `Error:` line with exit 1 (data) or 2 (usage) and no output
    file; never a traceback."""
    from hypothesis import HealthCheck, given, settings
    from hypothesis import strategies as st

    from tests.test_track_files import FUZZ_EXAMPLES

    root, model_id = tiny_model
    folder = tmp_path_factory.mktemp("predict_door")
    number = st.one_of(
        st.floats(-40, 40, allow_nan=False).map(lambda v: f"{v:.3f}"),
        st.sampled_from(["nan", "inf", "-inf", "1e30", "1e7", "", "x", "0", "-0", "1,5", "  2.0 "]),
    )
    row = st.tuples(
        st.one_of(st.integers(0, 12).map(lambda t: f"{t * 0.4:.1f}"), number),
        st.one_of(st.integers(1, 3).map(str), st.sampled_from(["a", "99999999999999999999999", "-1", "1.5"])),
        number,
        number,
    )
    steady = [(f"{t * 0.4:.1f}", str(agent), f"{t * 0.5:.2f}", f"{agent:.1f}") for agent in (1, 2) for t in range(10)]

    @settings(max_examples=FUZZ_EXAMPLES, deadline=None, suppress_health_check=list(HealthCheck))
    @given(
        rows=st.one_of(st.lists(row, max_size=30), st.lists(row, max_size=6).map(lambda extra: steady + extra)),
        header=st.sampled_from(["time,agent_id,x,y", "\ufefftime,agent_id,x,y", "time,agent,x", "t;id;x;y", ""]),
        k=st.sampled_from(["1", "5", "0", "-3", "2.5", "100000", "abc"]),
        at=st.sampled_from([None, "last", "all", "3.6", "7.6,100", "1e300", "nan", "-1"]),
        seed=st.sampled_from([None, "0", "7", "-1", "1e3", str(2**70)]),
    )
    def check(rows: list[tuple[str, ...]], header: str, k: str, at: str | None, seed: str | None) -> None:
        tracks, out = folder / "tracks.csv", folder / "futures.parquet"
        tracks.write_text("\n".join([header, *(",".join(r) for r in rows)]) + "\n", encoding="utf-8")
        out.unlink(missing_ok=True)
        args = ["predict", str(tracks), "--model", model_id, "--root", str(root), "--k", k, "--out", str(out)]
        args += ["--at", at] if at is not None else []
        args += ["--seed", seed] if seed is not None else []
        result = CliRunner().invoke(app, args)
        if result.exit_code == 0:
            futures = pd.read_parquet(out)
            assert len(futures) and np.isfinite(futures[["x", "y"]].to_numpy()).all()
            return
        assert result.exit_code in (1, 2), result.output
        assert result.exception is None or isinstance(result.exception, SystemExit), result.output
        lines = [line for line in result.output.strip().splitlines() if line.strip()]
        assert (lines and lines[0].startswith("Error:")) or "Usage:" in result.output, result.output
        if result.exit_code == 1:
            assert len(lines) == 1, result.output
        assert not out.exists()

    check()


def test_with_the_mean_code_each_goal_is_its_most_likely_future(tiny_cvaes: dict[str, object], tmp_path: Path) -> None:
    """evaluate.fair_code = "mean": with K goals per agent, sample k is the most-likely future toward goal k
    (the same for every seed); with prior draws the seed moves the samples."""
    root, dr = tiny_cvaes["root"], tiny_cvaes["dr"]
    drawn = load(dr, root=root)
    mean = dataclasses.replace(drawn, fair_code="mean")
    past = read_tracks(_walkers(tmp_path / "t.csv"))[["x", "y"]].to_numpy().reshape(1, 2, 10, 2)[:, :, -8:]
    mask = np.ones((1, 2), bool)
    goals = past[:, :, -1, None] + np.array([[3.0, 0.0], [2.0, 1.5], [-1.0, 2.5]], np.float32)  # (1, 2, 3, 2)
    futures = mean.predict(past, mask, k=3, goals=goals, seed=0)
    assert np.array_equal(futures, mean.predict(past, mask, k=3, goals=goals, seed=1))
    for k in range(3):
        toward = mean.most_likely(past, mask, goals=goals[:, :, k])
        np.testing.assert_allclose(futures[:, k], toward, atol=1e-5)
    assert not np.allclose(drawn.predict(past, mask, k=3, goals=goals, seed=0), futures, atol=1e-4)
