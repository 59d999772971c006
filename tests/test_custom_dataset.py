"""Any trajectory dataset through the whole pipeline: a crowd simulated with fftool's own social forces,
written as a dataset TOML + CSV files, ingested, trained on and reported like an ETH/UCY benchmark."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from fftool import pipeline
from fftool.artifacts.store import ArtifactStore
from fftool.cli import app
from fftool.config import load_config
from fftool.errors import UsageError
from fftool.science.crowd import simulate_crowd
from tests.test_maps import MATRIX, make_scene
from tests.test_reproduce import TINY_PIPELINE

# The tiny profile of tests/test_reproduce.py on a dataset instead of ETH/UCY (report.benchmarks left to
# its default, the dataset's one name).
TINY_DATASET_PIPELINE = TINY_PIPELINE.replace(
    "raw_dir = {raw!r}\nscenes_dir = {scenes!r}", "dataset = {dataset!r}"
).replace('benchmarks = ["zara1"]\n', "")


@pytest.fixture(scope="module")
def crowd(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A tiny simulated crowd written as a dataset: crowd/dataset.toml with train/val/test.csv."""
    out = tmp_path_factory.mktemp("sim") / "crowd"
    result = CliRunner().invoke(app, ["simulate-crowd", str(out), "--agents", "40", "--seconds", "120", "--seed", "0"])
    assert result.exit_code == 0, result.output
    return out / "dataset.toml"


def test_the_simulator_is_deterministic_for_a_seed() -> None:
    first, again, other = (simulate_crowd(12, 40.0, seed) for seed in (3, 3, 4))
    assert first.time_s.size > 100
    for name in ("time_s", "agent", "xy"):
        np.testing.assert_array_equal(getattr(first, name), getattr(again, name))
    assert first.xy.shape != other.xy.shape or not np.array_equal(first.xy, other.xy)
    steps = np.diff(np.unique(first.time_s))
    assert np.allclose(steps, 0.4)  # sampled at the benchmark's step
    # pedestrians walk: speeds between two samples are those of people, not teleports
    frame = pd.DataFrame({"t": first.time_s, "a": first.agent, "x": first.xy[:, 0], "y": first.xy[:, 1]})
    frame = frame.sort_values(["a", "t"])
    same = frame["a"].diff().eq(0)
    speed = np.hypot(frame["x"].diff(), frame["y"].diff())[same] / 0.4
    assert 0.5 < speed.median() < 2.0 and speed.max() < 3.0


@pytest.mark.slow
def test_reproduce_runs_on_the_simulated_dataset(crowd: Path, tmp_path: Path) -> None:
    profile = tmp_path / "tiny.toml"
    profile.write_text(TINY_DATASET_PIPELINE.format(dataset=str(crowd)))
    root = tmp_path / "artifacts"
    ingest = CliRunner().invoke(app, ["ingest", "-c", str(profile), "--root", str(root)])
    assert ingest.exit_code == 0, ingest.output
    assert "crowd" in ingest.output and "eth" not in ingest.output.split()
    result = CliRunner().invoke(app, ["reproduce", str(profile), "--root", str(root), "--device", "cpu"])
    assert result.exit_code == 0, result.output
    assert "no scene_image + homography" in result.output  # a blank map, said once, and goal variants still run
    report = root / "reports" / "tiny"
    table2 = pd.read_csv(report / "table2_ade_fde.csv").set_index("method")
    assert "crowd" in " ".join(table2.columns)
    results = pd.read_csv(report / "results.csv")
    assert set(results["benchmark"]) == {"crowd"} and set(results["variant"]) == {"cv", "baseline", "dr"}
    assert (results["agent_windows"] > 0).all()
    windows = json.loads(next((root / "windows").iterdir()).joinpath("manifest.json").read_text())["stats"]
    assert [(row["benchmark"], row["part"]) for row in windows["summary"]] == [
        ("crowd", "train"), ("crowd", "val"), ("crowd", "test"),
    ]  # fmt: skip
    assert windows["summary"][2]["sources"] == ["crowd/test.csv:test"]


def test_an_edited_file_rebuilds_and_the_benchmark_is_checked(crowd: Path, tmp_path: Path) -> None:
    copy = tmp_path / "crowd"
    copy.mkdir()
    for path in crowd.parent.iterdir():
        (copy / path.name).write_bytes(path.read_bytes())
    cfg = load_config(None, [f"data.dataset={str(copy / 'dataset.toml')!r}"])
    assert cfg.report.benchmarks == ("crowd",)
    before = pipeline.resolve(cfg, ["windows"])[0].fingerprint
    assert pipeline.resolve(cfg, ["windows"])[0].fingerprint == before
    test_csv = copy / "test.csv"
    test_csv.write_text(test_csv.read_text().replace(",0.", ",1.", 1))
    assert pipeline.resolve(cfg, ["windows"])[0].fingerprint != before  # content, not path, is hashed
    with pytest.raises(UsageError, match="got benchmark 'zara1'; the data offers crowd"):
        pipeline.resolve(cfg, ["goal"], "zara1")


def test_a_scene_image_with_its_homography_gives_the_dataset_a_map(crowd: Path, tmp_path: Path) -> None:
    scene = make_scene(tmp_path / "scene")
    np.savetxt(scene / "H.txt", np.linalg.inv(MATRIX))  # pixel -> world, as ETH's H.txt
    toml = tmp_path / "dataset.toml"
    text = crowd.read_text().replace('"train.csv"', f'"{crowd.parent / "train.csv"}"')
    text = text.replace('"val.csv"', f'"{crowd.parent / "val.csv"}"').replace(
        '"test.csv"', f'"{crowd.parent / "test.csv"}"'
    )
    toml.write_text(
        text.replace("[columns]", 'scene_image = "scene/reference.png"\nhomography = "scene/H.txt"\n\n[columns]')
    )
    cfg = load_config(None, [f"data.dataset={str(toml)!r}", "maps.colour_clusters=2"])
    built = pipeline.run(cfg, ArtifactStore(tmp_path / "artifacts"), ["maps"])["maps"]
    assert built.manifest.stats["without_geometry"] == [] and list(built.manifest.stats["scenes"]) == ["crowd"]
    assert built.manifest.stats["scenes"]["crowd"]["origin_x_m"] == pytest.approx(-0.5 - 2.0)  # as ETH/UCY's


GOOD = """name = "mine"
time_step_s = 0.4
units = "m"

[columns]
time = "time"
agent = "agent_id"

[files]
train = ["train.csv"]
val = ["val.csv"]
test = ["test.csv"]
"""


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda t: t.replace('name = "mine"\n', ""), r"dataset.toml: name: missing$"),
        (lambda t: t.replace('units = "m"', 'units = "furlong"'), r"dataset.toml: units: Input should be 'm', 'cm'"),
        (
            lambda t: t.replace('name = "mine"', 'name = "zara1"'),
            r"dataset.toml: name: 'zara1' is an ETH/UCY benchmark",
        ),
        (lambda t: t.replace("time_step_s = 0.4", "time_step_s = -1"), r"dataset.toml: time_step_s: Input should be"),
        (
            lambda t: t.replace('test = ["test.csv"]', 'test = ["gone.csv"]'),
            r"gone.csv: file not found \(files.test of",
        ),
        (lambda t: t + "colour = 1\n", r"dataset.toml: files.colour: unknown field"),
        (
            lambda t: t.replace('test = ["test.csv"]', 'test = ["./train.csv"]'),
            r"dataset.toml: files.train 'train.csv' and files.test './train.csv' hold the same bytes: test numbers "
            r"would measure training data; .*allow_shared_files = true",
        ),
        (
            lambda t: t.replace('test = ["test.csv"]', 'test = ["sub/../train.csv"]'),
            r"files.train 'train.csv' and files.test 'sub/../train.csv' hold the same bytes",
        ),
        (lambda t: t.replace('test = ["test.csv"]', 'test = ["link.csv"]'), r"and files.test 'link.csv' hold the same"),
        (lambda t: t.replace('test = ["test.csv"]', 'test = ["copy.csv"]'), r"and files.test 'copy.csv' hold the same"),
        (
            lambda t: t.replace('train = ["train.csv"]', 'train = ["train.csv", "copy.csv"]'),
            r"files.train 'train.csv' and files.train 'copy.csv' hold the same bytes: its rows would count twice",
        ),
    ],
    ids=["missing-field", "unknown-unit", "name-clash", "negative-step", "missing-file", "unknown-field", "shared",
         "other-spelling", "link", "copy", "twice-in-one-part"],
)  # fmt: skip
def test_a_bad_dataset_toml_is_one_line_naming_file_and_field(tmp_path: Path, edit, message: str) -> None:
    for i, part in enumerate(("train", "val", "test")):
        (tmp_path / f"{part}.csv").write_text(f"time,agent_id,x,y\n0,1,{i},0\n0.4,1,{i + 0.5},0\n")
    (tmp_path / "sub").mkdir()
    (tmp_path / "link.csv").symlink_to(tmp_path / "train.csv")
    (tmp_path / "copy.csv").write_bytes((tmp_path / "train.csv").read_bytes())
    (tmp_path / "dataset.toml").write_text(edit(GOOD))
    result = CliRunner().invoke(app, ["ingest", "--dataset", str(tmp_path / "dataset.toml"), "--root", str(tmp_path)])
    assert result.exit_code in (1, 2), result.output
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("Error: "), result.output
    assert re.search(message, lines[0]), lines[0]


def test_a_shared_file_is_accepted_when_the_toml_says_so_and_changes_no_fingerprint(tmp_path: Path) -> None:
    from fftool.dataset.custom import load_dataset

    for i, part in enumerate(("train", "val", "test")):
        (tmp_path / f"{part}.csv").write_text(f"time,agent_id,x,y\n0,1,{i},0\n0.4,1,{i + 0.5},0\n")
    (tmp_path / "a.toml").write_text(GOOD)
    (tmp_path / "b.toml").write_text(GOOD.replace("[columns]", "allow_shared_files = true\n\n[columns]"))
    assert load_dataset(tmp_path / "a.toml").input_hashes() == load_dataset(tmp_path / "b.toml").input_hashes()
    shared = GOOD.replace('val = ["val.csv"]', 'val = ["train.csv"]')
    (tmp_path / "c.toml").write_text(shared.replace("[columns]", "allow_shared_files = true\n\n[columns]"))
    assert load_dataset(tmp_path / "c.toml").spec.files.val == ["train.csv"]
    load_dataset(tmp_path / "c.toml").input_hashes()  # accepted knowingly
