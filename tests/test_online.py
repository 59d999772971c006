"""The online predictor: the numbers of `fftool predict --at t` on the same tracks, a stream at any rate with
jitter and dropped frames, bounded memory, and bad updates refused with the state unharmed."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from fftool.api import load, predict_tracks
from fftool.cli import app
from fftool.dataset.stream import DetectionBuffer
from fftool.errors import FftoolError, InputError, UsageError
from fftool.online import OnlinePredictor

from .conftest import REAL_RAW

ZARA1 = REAL_RAW / "all_data" / "crowds_zara01.txt"


@pytest.fixture
def tiny(tiny_cvaes: dict[str, object]) -> dict[str, object]:
    """The shared tiny baseline and dr CVAEs (conftest.tiny_cvaes)."""
    return tiny_cvaes


def _zara1(first_s: float, last_s: float) -> pd.DataFrame:
    """Real zara1 rows (time_s, agent, x, y) between two times: 2.5 Hz, frames 0.04 s apart."""
    if not ZARA1.is_file():
        pytest.skip(f"real data absent: {ZARA1}")
    rows = np.loadtxt(ZARA1)
    table = pd.DataFrame({"time_s": rows[:, 0] * 0.04, "agent": rows[:, 1].astype(np.int64)})
    table[["x", "y"]] = rows[:, 2:4]
    table = table[table["time_s"].between(first_s, last_s)]
    return table.sort_values(["agent", "time_s"], kind="stable").reset_index(drop=True)


def _same_to_rounding(got: np.ndarray, expected: np.ndarray) -> None:
    """predict's futures to float rounding: an update decodes its most-likely future in the same rollout (one more
    code per window), and a product one row larger may round the last bit otherwise on some CPUs."""
    assert got.shape == expected.shape and np.abs(got - expected).max() <= 1e-5


def _replay(online: OnlinePredictor, tracks: pd.DataFrame, goals: dict | None = None) -> dict[float, pd.DataFrame]:
    """Each distinct time of `tracks` fed as one update; the futures table of every update that predicted."""
    results = {}
    for time_s, rows in tracks.groupby("time_s", sort=True):
        detections = dict(zip(rows["agent"], zip(rows["x"], rows["y"])))
        now = {a: goals[a] for a in detections} if goals else None
        result = online.update(float(time_s), detections, goals=now)
        if len(result.agents):
            results[float(time_s)] = result.table()
    return results


@pytest.mark.data
@pytest.mark.parametrize("variant", ["baseline", "dr"])
def test_the_online_predictor_gives_the_numbers_of_predict_at_each_time(
    tiny: dict[str, object], variant: str, tmp_path: Path
) -> None:
    tracks = _zara1(40.0, 60.0)
    goals = None
    if variant == "dr":  # a goal for every agent: its last position in the recording
        last = tracks.groupby("agent")[["x", "y"]].last()
        goals = {a: (float(x), float(y)) for a, (x, y) in last.iterrows()}
        pd.DataFrame({"agent": last.index, "x": last["x"], "y": last["y"]}).to_csv(tmp_path / "goals.csv", index=False)
    online = OnlinePredictor(tiny[variant], root=tiny["root"], k=20, seed=4)
    results = _replay(online, tracks, goals)
    assert len(results) > 30
    tracks.rename(columns={"time_s": "time"}).to_csv(tmp_path / "tracks.csv", index=False)
    for time_s in list(results)[:: len(results) // 3][:3]:  # three times, each in a command of its own
        out = tmp_path / f"at_{time_s:.2f}.parquet"
        args = ["predict", str(tmp_path / "tracks.csv"), "--model", tiny[variant], "--root", str(tiny["root"])]
        args += ["--at", f"{time_s:.2f}", "--seed", "4", "--out", str(out)]
        args += ["--goals", str(tmp_path / "goals.csv")] if goals else []
        result = CliRunner().invoke(app, args)
        assert result.exit_code == 0, result.output
        expected = pd.read_parquet(out).sort_values(["agent", "sample", "step"], kind="stable")
        got = results[time_s]
        assert got["agent"].tolist() == expected["agent"].tolist()
        _same_to_rounding(got[["x", "y"]].to_numpy(), expected[["x", "y"]].to_numpy())


@pytest.mark.data
def test_each_update_gives_the_most_likely_future_of_predict(tiny: dict[str, object]) -> None:
    """Beside the K samples, every update carries one most-likely future per agent: `predict --most-likely`'s."""
    tracks = _zara1(40.0, 48.0)
    online, last = OnlinePredictor(tiny["baseline"], root=tiny["root"], k=20, seed=4), None
    for time_s, rows in tracks.groupby("time_s", sort=True):
        result = online.update(float(time_s), dict(zip(rows["agent"], zip(rows["x"], rows["y"]))))
        last = result if len(result.agents) else last
    assert last is not None and last.most_likely.shape == (len(last.agents), 12, 2)
    model = load(tiny["baseline"], root=tiny["root"])
    table, _ = predict_tracks(model, tracks, at=[last.time_s], k=20, seed=4, most_likely=True)
    table = table.sort_values(["agent", "step"], kind="stable")
    assert table["agent"].unique().tolist() == last.agents.tolist()
    _same_to_rounding(table[["x", "y"]].to_numpy().reshape(-1, 12, 2), last.most_likely)


@pytest.mark.data
def test_a_jittered_stream_with_dropped_frames_gives_predicts_numbers_on_what_it_saw(tiny: dict[str, object]) -> None:
    """10 Hz detections with ±20 ms jitter, one in ten dropped: each prediction equals `predict_tracks` on all the
    detections received so far (resampled the same way), although the predictor keeps only the last few seconds."""
    tracks = _zara1(40.0, 56.0)
    rng = np.random.default_rng(0)
    times = np.arange(41.0, 55.0, 0.1) + rng.uniform(-0.02, 0.02, 140)
    model = load(tiny["baseline"], root=tiny["root"])
    online = OnlinePredictor(model, k=6, seed=1)
    seen, compared = [], 0
    for i, time_s in enumerate(times):
        detections = {}
        for agent, rows in tracks.groupby("agent"):
            t = rows["time_s"].to_numpy()
            if t[0] <= time_s <= t[-1] and rng.random() > 0.1:
                detections[agent] = (np.interp(time_s, t, rows["x"]), np.interp(time_s, t, rows["y"]))
        result = online.update(time_s, detections)
        seen += [(time_s, a, x, y) for a, (x, y) in detections.items()]
        assert set(result.agents) <= set(detections)
        if i % 10 == 9 and len(result.agents):
            table = pd.DataFrame(seen, columns=["time_s", "agent", "x", "y"]).sort_values(["agent", "time_s"])
            expected, _ = predict_tracks(model, table, at="last", k=6, seed=1)
            _same_to_rounding(result.table()[["x", "y"]].to_numpy(), expected[["x", "y"]].to_numpy())
            compared += 1
    assert compared >= 8
    assert len(online.buffer.time) < len(seen) / 3  # it kept a few seconds, not the stream


def test_an_agent_back_after_a_long_gap_starts_a_new_track(tiny: dict[str, object]) -> None:
    online = OnlinePredictor(tiny["baseline"], root=tiny["root"], k=2, max_gap_s=1.0)
    walk = lambda t: (0.5 * t, 1.0)  # noqa: E731
    predicted_at = []
    for step in range(30):
        t = 0.4 * step
        if 10 <= step < 13:  # 1.2 s without agent 7: longer than max_gap_s
            result = online.update(t, {8: (0.0, 0.3 * t)})
        else:
            result = online.update(t, {7: walk(t), 8: (0.0, 0.3 * t)})
        predicted_at.append(7 in result.agents)
    assert predicted_at[7:10] == [True] * 3  # eight steps seen: predicted
    assert not any(predicted_at[10:20])  # after the gap: its old steps are gone, eight new ones are needed
    assert all(predicted_at[20:])


def test_memory_stays_bounded_over_a_long_stream() -> None:
    """10,000 updates of a crowd that keeps changing: the buffer holds one horizon of the agents in view."""
    buffer = DetectionBuffer(horizon_s=3.8, max_gap_s=1.0)
    rng = np.random.default_rng(0)
    largest = 0
    for step in range(10_000):
        t = 0.1 * step + rng.uniform(-0.02, 0.02)
        in_view = np.arange(step // 50, step // 50 + 20)  # 20 agents, one replaced every 5 s
        seen = in_view[rng.random(20) > 0.2]
        buffer.add(t, seen.astype(object), rng.normal(size=(len(seen), 2)))
        largest = max(largest, len(buffer.time))
    assert largest <= 20 * (3.8 / 0.1 + 2)
    assert set(buffer.agents) <= set(range(step // 50 - 1, step // 50 + 20))  # gone agents are forgotten


@pytest.mark.parametrize(
    ("time_s", "detections", "message"),
    [
        (float("nan"), {1: (0.0, 0.0)}, "finite number of seconds"),
        (float("inf"), {1: (0.0, 0.0)}, "finite number of seconds"),
        ("soon", {1: (0.0, 0.0)}, "number of seconds"),
        (1.0, {1: (0.0, 0.0)}, "not after the last update's 1.2 s"),
        (1.2, {1: (0.0, 0.0)}, "not after the last update's 1.2 s"),
        (1.6, {1: (float("nan"), 0.0)}, "agent 1 at 1.6 s: [nan, 0.0] is not a finite coordinate"),
        (1.6, {1: (0.0, 1e9)}, "not a finite coordinate within"),
        (1.6, {1: (0.0,)}, "agent 1 at 1.6 s: (0.0,) is not an (x, y) pair of numbers"),
        (1.6, {1: ("a", 2.0)}, "is not an (x, y) pair of numbers"),
        (1.6, {"ped": (0.0, 0.0)}, "agent id 'ped': expected ids of one kind for the whole stream"),
        (1.6, {True: (0.0, 0.0)}, "agent id True"),
        (1.6, [(0.0, 0.0)], "expected a mapping of agent id to (x, y)"),
    ],
)
def test_a_bad_update_is_one_clear_error_and_changes_nothing(
    tiny: dict[str, object], time_s: object, detections: object, message: str
) -> None:
    model = load(tiny["baseline"], root=tiny["root"])
    online, untouched = OnlinePredictor(model, k=3), OnlinePredictor(model, k=3)
    for t in np.arange(4) * 0.4:
        for predictor in (online, untouched):
            predictor.update(float(t), {1: (t, 0.0), 2: (0.0, t)})
    state = lambda: (online.buffer.time.copy(), online.buffer.agent.copy(), online.buffer.xy.copy())  # noqa: E731
    before = state()
    with pytest.raises(InputError) as error:
        online.update(time_s, detections)
    assert message in str(error.value) and "\n" not in str(error.value)
    assert all(
        np.array_equal(a, b) for a, b in zip(before, (online.buffer.time, online.buffer.agent, online.buffer.xy))
    )
    for t in np.arange(4, 10) * 0.4:  # and it goes on as if the bad update had never come
        got, expected = (p.update(float(t), {1: (t, 0.0), 2: (0.0, t)}) for p in (online, untouched))
    assert np.array_equal(got.futures, expected.futures) and len(got.agents) == 2


def test_generated_streams_give_finite_futures_or_one_clear_error_and_keep_the_state(tiny: dict[str, object]) -> None:
    """Hypothesis draws streams of updates: times (going back, repeated, NaN, inf included), ids of both kinds,
    positions (NaN, inf, huge, wrong shapes included). Each update returns finite futures for agents it saw, or
    raises InputError with the buffer unchanged; never a traceback, never NaN out of finite input."""
    from hypothesis import HealthCheck, event, given, settings
    from hypothesis import strategies as st

    from tests.test_track_files import FUZZ_EXAMPLES

    model = load(tiny["baseline"], root=tiny["root"])
    number = st.one_of(st.floats(-20, 20), st.sampled_from([np.nan, np.inf, -np.inf, 1e30, 0.0]))
    position = st.one_of(st.tuples(number, number), st.sampled_from([(0.0,), (1.0, 2.0, 3.0), ("a", 1.0), None]))
    agent = st.one_of(st.integers(0, 5), st.sampled_from(["a", "b", True]))
    step = st.one_of(st.floats(0.05, 0.6), st.sampled_from([0.0, -0.4, np.nan, np.inf]))
    good = st.tuples(
        st.floats(0.3, 0.5), st.fixed_dictionaries({a: st.tuples(*[st.floats(-20, 20)] * 2) for a in range(3)})
    )
    update = st.one_of(good, good, good, st.tuples(step, st.dictionaries(agent, position, max_size=4)))

    @settings(max_examples=FUZZ_EXAMPLES, deadline=None, suppress_health_check=list(HealthCheck))
    @given(st.lists(update, min_size=8, max_size=25))
    def check(updates: list) -> None:
        online, t = OnlinePredictor(model, k=3, seed=0), 0.0
        for dt, detections in updates:
            t = t + dt if np.isfinite(dt) else dt
            before = (online.buffer.time.copy(), online.buffer.agent.copy(), online.buffer.xy.copy())
            try:
                result = online.update(t, detections)
            except InputError as exc:
                assert "\n" not in str(exc)
                after = (online.buffer.time, online.buffer.agent, online.buffer.xy)
                assert all(np.array_equal(a, b) for a, b in zip(before, after))
                t = online.buffer.last_time_s if online.buffer.last_time_s is not None else 0.0
                continue
            assert set(result.agents) <= set(detections)
            assert np.isfinite(result.futures).all() and result.futures.shape[1:] == (3, 12, 2)
            event(f"predicted {min(len(result.agents), 1)}")

    check()


def test_an_update_that_fails_half_way_leaves_the_predictor_as_it_was(tiny: dict[str, object]) -> None:
    """A goal variant's update without a goal for one agent fails after its detections were buffered and its
    clock moved: once the retry with the goal was refused as 'not after the last update'."""
    model = load(tiny["dr"], root=tiny["root"])
    online, clean = OnlinePredictor(model, k=3), OnlinePredictor(model, k=3)
    goals = {1: (9.0, 0.0), 2: (0.0, 9.0)}
    for t in np.arange(8) * 0.4:
        for predictor in (online, clean):
            predictor.update(float(t), {1: (t, 0.0), 2: (0.0, t)}, goals=goals)
    with pytest.raises(FftoolError, match="no goal given for agent"):
        online.update(3.2, {1: (3.2, 0.0), 2: (0.0, 3.2)}, goals={1: (9.0, 0.0)})
    got, expected = (p.update(3.2, {1: (3.2, 0.0), 2: (0.0, 3.2)}, goals=goals) for p in (online, clean))
    assert np.array_equal(got.futures, expected.futures)


def test_two_threads_updating_one_predictor_get_a_clear_refusal(
    tiny: dict[str, object], monkeypatch: pytest.MonkeyPatch
) -> None:
    import threading

    model = load(tiny["baseline"], root=tiny["root"])
    online = OnlinePredictor(model, k=3)
    inside, release = threading.Event(), threading.Event()
    checked = online._checked

    def slow(*args: object) -> object:
        inside.set()
        release.wait(10)
        return checked(*args)

    monkeypatch.setattr(online, "_checked", slow)
    first = threading.Thread(target=online.update, args=(0.0, {1: (0.0, 0.0)}))
    first.start()
    inside.wait(10)
    with pytest.raises(UsageError, match="called again while an update runs"):
        online.update(0.4, {1: (0.4, 0.0)})
    release.set()
    first.join(10)
    assert online.buffer.last_time_s == 0.0
