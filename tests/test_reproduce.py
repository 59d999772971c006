"""End to end on a tiny synthetic dataset: `fftool reproduce` builds the whole DAG, writes the tables with
the numbers of its evaluations, and a second run rebuilds nothing."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from fftool.artifacts.store import ArtifactStore
from fftool.cli import app
from fftool.learning.batches import load_agent_windows
from fftool.reporting import ablation
from fftool.reporting.rescoring import rescore
from tests.test_maps import make_scene

TINY_PIPELINE = """
[data]
raw_dir = {raw!r}
scenes_dir = {scenes!r}

[goal]
resolution_m = 0.5
crop_cells = 16
widths = [4, 8, 8]
epochs = 1

[goals]
samples = 100

[cvae]
d_model = 16
n_heads = 2
d_ff = 32
n_layers = 1
z_dim = 4
epochs = 1
train_k = 2
val_max_windows = 4

[dlow]
epochs = 1
qnet_hidden = [8]
val_max_windows = 4

[evaluate]
k = 20

[report]
benchmarks = ["zara1"]
variants = ["dr"]
"""


@pytest.mark.slow
def test_reproduce_builds_everything_then_reuses_it(raw_tree: Path, tmp_path: Path) -> None:
    make_scene(tmp_path / "scenes" / "zara1")
    profile = tmp_path / "tiny.toml"
    profile.write_text(TINY_PIPELINE.format(raw=str(raw_tree), scenes=str(tmp_path / "scenes")))
    root = tmp_path / "artifacts"
    common = ["-c", str(profile), "--root", str(root)]
    early = CliRunner().invoke(app, ["evaluate", "--variant", "dr", *common])
    assert early.exit_code == 1 and "fftool ingest" in early.output and not root.joinpath("evaluate").exists()
    assert CliRunner().invoke(app, ["ablate", "--variants", "dr,teleport", *common]).exit_code == 2
    args = ["reproduce", str(profile), "--root", str(root), "--device", "cpu"]
    first = CliRunner().invoke(app, args)
    assert first.exit_code == 0, first.output
    assert "run summary" in first.output and "tracks, windows" in first.output
    report = root / "reports" / "tiny"
    assert (report / "report.md").is_file() and "Table IV" in (report / "report.md").read_text()
    listed = CliRunner().invoke(app, ["artifacts", "list", "--kind", "report", "--root", str(root)])
    assert listed.exit_code == 0 and "tiny" in listed.output and "3 evaluations" in listed.output
    [stored] = ArtifactStore(root).list("report")  # the published folder is the stored report and its marker
    assert sorted(p.name for p in report.iterdir()) == sorted([*stored.manifest.files, ablation.REPORT_MARKER])
    assert stored.id in (report / ablation.REPORT_MARKER).read_text()
    for stem in ("table2_ade_fde", "table3_fde", "table4_collisions", "table5_collision_metrics", "table6_paired"):
        assert {p.suffix for p in report.glob(f"{stem}.*")} == {".md", ".csv", ".tex"}

    manifests, folders = {}, {}
    for folder in (root / "evaluate").iterdir():
        stats = json.loads((folder / "manifest.json").read_text())["stats"]
        manifests[stats["variant"]], folders[stats["variant"]] = stats, folder.name
    assert set(manifests) == {"cv", "baseline", "dr"}
    assert manifests["dr"]["protocol"] == "fair" and manifests["baseline"]["protocol"] == "none"
    table3 = pd.read_csv(report / "table3_fde.csv").set_index("method")
    assert table3.loc["ForceFormer-Dr", "zara1"] == pytest.approx(manifests["dr"]["min_fde"], rel=1e-5)
    assert table3.loc["ForceFormer-Dr", "zara1 low"] <= table3.loc["ForceFormer-Dr", "zara1"]
    assert table3.loc["ForceFormer-Dr", "zara1"] <= table3.loc["ForceFormer-Dr", "zara1 high"]
    assert table3.loc["ForceFormer-Dr", "zara1 (paper)"] == 0.20
    table4 = pd.read_csv(report / "table4_collisions.csv").set_index("method")
    assert table4.loc["AgentFormer", "zara1"] == manifests["baseline"]["nc"]["best_ade"]["ordered"]
    table5 = pd.read_csv(report / "table5_collision_metrics.csv").set_index("method")
    assert table5.loc["ForceFormer-Dr", "zara1 COL"] == pytest.approx(manifests["dr"]["col"], rel=1e-5)
    assert table5.loc["ForceFormer-Dr", "zara1 Col-II"] == manifests["dr"]["col_gt"]
    table2 = pd.read_csv(report / "table2_ade_fde.csv").set_index("method")
    assert table5.loc["ForceFormer-Dr", "zara1 JADE"] >= table2.loc["ForceFormer-Dr", "zara1 minADE"]  # joint ≥ own
    assert table2.loc["Y-net with TTST (ICCV'21), published, not re-run", "zara1 (paper)"] == "0.17/0.27"
    assert (report / "scores.png").is_file() and "![scores](scores.png)" in (report / "report.md").read_text()
    results = pd.read_csv(report / "results.csv")
    assert len(results) == 3 and results["grid_seed"].isna().all()  # no --seeds: each section's own seed
    folder = next(f for f in (root / "evaluate").iterdir() if f.name.startswith(folders["dr"]))
    predictions = pd.read_parquet(folder / "predictions.parquet")
    assert len(predictions) == manifests["dr"]["agent_windows"] and len(predictions["pred"].iloc[0]) == 20 * 12 * 2
    windows = ArtifactStore(root).list("windows")[0]
    data = load_agent_windows(windows, "zara1", "test")
    same = rescore(predictions, data, 20, 0.1)  # metrics again from the saved predictions alone
    np.testing.assert_allclose(same["min_ade"], predictions["min_ade"], rtol=1e-5)
    np.testing.assert_array_equal(same["collisions"], predictions["collisions"])
    wider = rescore(predictions, data, 20, 50.0)
    assert wider["collisions"].sum() > same["collisions"].sum()
    command = ["rescore", f"evaluate/{folders['dr']}", "--threshold", "50", "--root", str(root)]
    rescored = CliRunner().invoke(app, command)
    assert rescored.exit_code == 0, rescored.output
    stored_row, new_row = (
        line.split() for line in rescored.output.splitlines() if line.lstrip().startswith(("stored", "re-scored"))
    )
    assert new_row[1:] == [
        "50",
        f"{np.mean(wider['min_ade']):.3f}",
        f"{np.mean(wider['min_fde']):.3f}",
        str(wider["collisions"].sum()),
        str(wider["collisions"].sum() // 2),
        str(wider["joint_collisions"].sum()),
        str(wider["joint_collisions"].sum() // 2),
        f"{np.mean(wider['col']):.2f}",  # COL and Col-II do not depend on γ
        str(wider["col_gt"].sum()),
    ]
    assert stored_row[1] == "0.1" and stored_row[4] == str(manifests["dr"]["nc"]["best_ade"]["ordered"])
    not_evaluate = CliRunner().invoke(app, ["rescore", "windows", "--threshold", "0.2", "--root", str(root)])
    assert not_evaluate.exit_code == 1 and "expected 'evaluate'" in not_evaluate.output

    first_report = (report / "report.md").read_text()
    again = CliRunner().invoke(app, args)
    assert again.exit_code == 0, again.output
    assert "0 of 11 stage builds to run" in again.output and "building" not in again.output
    assert again.output.count("evaluate' is cached") == 3 and "report report/" in again.output
    assert (report / "report.md").read_text() == first_report  # the stored report, with its own wall time
    stored_md = stored.path / "report.md"
    stored_md.write_text(first_report + "edited")
    damaged = CliRunner().invoke(app, args)
    assert damaged.exit_code == 1 and "changed since it was built" in damaged.output
    assert (report / "report.md").read_text() == first_report  # nothing published from it
    stored_md.write_text(first_report)
    assert "run summary" in again.output and again.output.count("nothing (all reused)") == 3
    paper = CliRunner().invoke(app, ["ablate", "--protocol", "paper", *common, "--out", str(tmp_path / "paper")])
    assert paper.exit_code == 0, paper.output
    assert paper.output.count("building") == 1  # only dr reads goals; baseline and cv are shared
    assert "goal protocol 'paper'" in (tmp_path / "paper" / "report.md").read_text()

    seeds_out = tmp_path / "seeds"
    seeded = CliRunner().invoke(app, ["ablate", "--seeds", "0,1", *common, "--out", str(seeds_out)])
    assert seeded.exit_code == 0, seeded.output
    assert "seed" in seeded.output and seeded.output.count("nothing (all reused)") == 3  # seed 0 is cached
    per_seed = pd.read_csv(seeds_out / "results.csv")
    assert sorted(per_seed["grid_seed"]) == [0, 0, 0, 1, 1, 1]
    assert set(per_seed.loc[per_seed["grid_seed"] == 0, "artifact"]) == {f"evaluate/{f}" for f in folders.values()}
    table3 = pd.read_csv(seeds_out / "table3_fde.csv").set_index("method")
    values = [float(v) for v in table3.loc["ForceFormer-Dr", "zara1 per seed"].split(";")]
    assert values == pytest.approx(
        per_seed.query("variant == 'dr'").sort_values("grid_seed")["min_fde"].tolist(), abs=1e-5
    )
    assert table3.loc["ForceFormer-Dr", "zara1"] == pytest.approx(np.mean(values), abs=1e-5)
    assert (
        " ±" in (seeds_out / "table3_fde.md").read_text() and "grid seeds 0, 1" in (seeds_out / "report.md").read_text()
    )
    bad = CliRunner().invoke(app, ["ablate", "--seeds", "0,x", *common, "--out", str(seeds_out)])
    assert bad.exit_code == 2 and "--seeds" in bad.output

    figures = tmp_path / "figures"
    drawn = CliRunner().invoke(
        app, ["plot", "--variants", "baseline,dr", "--count", "2", *common, "--out", str(figures)]
    )
    assert drawn.exit_code == 0, drawn.output
    assert {p.name for p in figures.iterdir()} == {"qualitative_zara1.png", "density_zara1.png"}
    missing = CliRunner().invoke(
        app, ["plot", "--variants", "dr", "--windows", "99999", *common, "--out", str(figures)]
    )
    assert missing.exit_code == 1 and "99999" in missing.output
