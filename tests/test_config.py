"""The config loader refuses, up front and naming the key, every value a stage would trip over later."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from typer.testing import CliRunner

from fftool.cli import app
from fftool.config import SECTIONS, PipelineConfig, load_config, predictor_config, variant_section
from fftool.dataset.scenes import BENCHMARK_TEST_SOURCES, BENCHMARKS
from fftool.errors import ConfigError
from fftool.paper import PAPER_NAMES
from fftool.variants import FORCEFORMER_VARIANTS, PREDICTORS

FLOAT_KEYS = [
    f"{section}.{name}"
    for section in SECTIONS
    for name, field in PipelineConfig.model_fields[section].annotation.model_fields.items()
    if field.annotation is float
]


def test_every_section_has_float_keys_to_check() -> None:
    sections = {key.split(".")[0] for key in FLOAT_KEYS}
    assert {"ingest", "forces", "maps", "goal", "goals", "cvae", "evaluate"} <= sections


@pytest.mark.parametrize("value", ["inf", "-inf", "nan"])
@pytest.mark.parametrize("key", FLOAT_KEYS)
def test_no_float_may_be_infinite_or_nan(key: str, value: str) -> None:
    with pytest.raises(ConfigError, match=rf"{key}: Input should be a finite number"):
        load_config(None, [f"{key}={value}"])


@pytest.mark.parametrize(
    ("override", "expected"),
    [
        ("cvae.epochs=0", "cvae.epochs: Input should be greater than 0"),
        ("goal.epochs=0", "goal.epochs: Input should be greater than 0"),
        ("cvae.batch_windows=0", "cvae.batch_windows: Input should be greater than 0"),
        ("goal.batch_size=0", "goal.batch_size: Input should be greater than 0"),
        ("evaluate.batch_windows=0", "evaluate.batch_windows: Input should be greater than 0"),
        ("cvae.k=0", "cvae.k: Input should be greater than 0"),
        ("cvae.train_k=0", "cvae.train_k: Input should be greater than 0"),
        ("goals.k=0", "goals.k: Input should be greater than 0"),
        ("evaluate.k=0", "evaluate.k: Input should be greater than 0"),
        ("cvae.warmup_fraction=1.0", "cvae.warmup_fraction: Input should be less than 1"),
        ("goal.warmup_fraction=-0.1", "goal.warmup_fraction: Input should be greater than or equal to 0"),
        ("cvae.dropout=1.0", "cvae.dropout: Input should be less than 1"),
        ("cvae.decay_gamma=1.5", "cvae.decay_gamma: Input should be less than or equal to 1"),
        ("goals.threshold=1", "goals.threshold: Input should be less than 1"),
        ("forces.fov_out_of_view=1.5", "forces.fov_out_of_view: Input should be less than or equal to 1"),
        ("windows.obs_len=1", "windows.obs_len: Input should be greater than or equal to 2"),
        ("goal.widths=[8]", "goal.widths: Tuple should have at least 2 items"),
        ("goal.widths=[8, 0]", "goal.widths.1: Input should be greater than 0"),
        ("goals.parts=[]", "goals.parts: Tuple should have at least 1 item"),
        ("report.benchmarks=[]", "report.benchmarks: Tuple should have at least 1 item"),
    ],
)
def test_ranges_are_checked_with_the_key_and_the_bound(override: str, expected: str) -> None:
    with pytest.raises(ConfigError, match=rf"{expected}.*\(got "):
        load_config(None, [override])


@pytest.mark.parametrize(
    ("overrides", "expected"),
    [
        (["cvae.n_heads=3"], "cvae.n_heads: expected a divisor of d_model = 256 (got 3)"),
        (["cvae.d_model=20", "cvae.n_heads=8"], "cvae.n_heads: expected a divisor of d_model = 20 (got 8)"),
        (["goal.crop_cells=20"], "goal.crop_cells: expected a multiple of 16 (2 ** (len(widths) - 1)) (got 20)"),
        (["goal.crop_cells=16", "goal.widths=[4, 8, 8]", "goal.heatmap_sigma_cells=7"], "goal.heatmap_sigma_cells: "),
        (["report.seeds=[0, 0]"], "report.seeds: expected distinct seeds (got [0, 0])"),
        (['cvae.output="goal_residual"'], "cvae.output: expected 'offset' or 'cv_residual' for the baseline, which"),
        (['cvae.output="relaxation_residual"'], "cvae.output: expected 'offset' or 'cv_residual' for the baseline"),
        (["cvae.relaxation_steps=0"], "cvae.relaxation_steps"),
    ],
)
def test_cross_field_checks_name_the_key_and_what_was_expected(overrides: list[str], expected: str) -> None:
    with pytest.raises(ConfigError) as caught:
        load_config(None, overrides)
    assert expected in str(caught.value)


def test_valid_cross_field_values_load() -> None:
    cfg = load_config(None, ["cvae.d_model=20", "cvae.n_heads=5", "goal.crop_cells=20", "goal.widths=[4, 8, 8]"])
    assert (cfg.cvae.d_model, cfg.cvae.n_heads, cfg.goal.crop_cells) == (20, 5, 20)


def test_a_file_that_is_not_utf8_text_is_a_config_error(tmp_path: Path) -> None:
    binary = tmp_path / "model.pt"
    binary.write_bytes(b"PK\x03\x04\x80\xff\xfe binary")
    with pytest.raises(
        ConfigError, match=rf"^{re.escape(str(binary))}: not a UTF-8 TOML file \(undecodable byte at offset 4\)$"
    ):
        load_config(binary)


def test_the_cli_reports_a_bad_value_as_a_usage_error(tmp_path: Path) -> None:
    runner = CliRunner()
    root = ["--root", str(tmp_path / "artifacts")]
    infinite = runner.invoke(app, ["train-cvae", *root, "--set", "cvae.lr=inf"])
    assert infinite.exit_code == 2 and "cvae.lr: Input should be a finite number (got inf)" in infinite.output
    binary = tmp_path / "weights.bin"
    binary.write_bytes(bytes(range(256)))
    unreadable = runner.invoke(app, ["train-goal", *root, "-c", str(binary)])
    assert unreadable.exit_code == 2 and "not a UTF-8 TOML file" in unreadable.output
    assert not (tmp_path / "artifacts").exists()


def test_the_name_lists_are_defined_once() -> None:
    # Literal types are the source; the mappings keyed by those names must cover exactly them.
    assert tuple(BENCHMARK_TEST_SOURCES) == BENCHMARKS == PipelineConfig().report.benchmarks
    assert tuple(PAPER_NAMES) == PREDICTORS and PipelineConfig().report.variants == FORCEFORMER_VARIANTS
    with pytest.raises(ConfigError, match=r"cvae\.variant"):
        load_config(overrides=["cvae.variant=teleport"])
    assert predictor_config(PipelineConfig(), "dr").cvae.variant == "dr"
    assert predictor_config(PipelineConfig(), "cv").evaluate.predictor == "cv"


@pytest.mark.parametrize("key", ["cvae.epochs", "cvae.lr", "goal.batch_size", "evaluate.k", "report.bootstrap_block"])
def test_a_boolean_is_never_read_as_a_number(tmp_path: Path, key: str) -> None:
    """`epochs = true` was read as 1 (pydantic's lax mode): a typo must be refused, naming the key."""
    section, name = key.split(".")
    path = tmp_path / "p.toml"
    path.write_text(f"[{section}]\n{name} = true\n")
    with pytest.raises(ConfigError, match=rf"{key}: Value error, expected .*not the boolean true"):
        load_config(path)
    assert load_config(None, ["cvae.rotate=false"]).cvae.rotate is False  # a boolean where one belongs


def test_a_variants_recipe_replaces_its_keys_for_that_variant_alone(tmp_path: Path) -> None:
    path = tmp_path / "p.toml"
    path.write_text("[cvae]\nepochs = 12\n\n[per_variant.baseline.cvae]\nbest_of_k_warmup_epochs = 2\nepochs = 20\n")
    cfg = load_config(path, ["per_variant.dr.dlow.qnet_hidden=[128, 64]"])
    baseline, dr = predictor_config(cfg, "baseline"), predictor_config(cfg, "dr")
    assert (variant_section(baseline, "cvae").epochs, variant_section(baseline, "cvae").best_of_k_warmup_epochs) == (
        20,
        2,
    )
    assert (variant_section(dr, "cvae").epochs, variant_section(dr, "cvae").best_of_k_warmup_epochs) == (12, 0)
    assert variant_section(dr, "dlow").qnet_hidden == (128, 64) and variant_section(baseline, "dlow").qnet_hidden == (
        512,
        256,
    )
    assert cfg.cvae.epochs == 12  # the section itself stays the profile's: switching variants loses nothing
    assert variant_section(predictor_config(baseline, "dr"), "cvae") == variant_section(dr, "cvae")


@pytest.mark.parametrize(
    ("override", "expected"),
    [
        ("per_variant.baseline.cvae.epoch=3", "per_variant.baseline.cvae.epoch: expected a key of the [cvae] section"),
        ("per_variant.dr.dlow.lr=-1", "per_variant.dr.dlow.lr: expected Input should be greater than 0 (got -1)"),
        (
            "per_variant.goal.cvae.n_heads=3",
            "per_variant.goal.cvae.n_heads: expected a divisor of d_model = 256 (got 3)",
        ),
        ("per_variant.re.cvae.seed=1", "per_variant.re.cvae.seed: expected a key the variants may differ in"),
        ("per_variant.baseline.cvae.variant='dr'", "per_variant.baseline.cvae.variant: expected a key the variants"),
        (
            "per_variant.baseline.cvae.output='goal_residual'",
            "per_variant.baseline.cvae.output: expected 'offset' or 'cv_residual' for the baseline",
        ),
        ("per_variant.baseline.goal.epochs=3", "unknown key 'per_variant.baseline.goal'"),
        ("per_variant.teleport.cvae.epochs=3", "per_variant.teleport"),
        ("per_variant.baseline.epochs=3", "expected section.key=value, e.g. ingest.frame_stride=10, or per_variant."),
        ("cvae.epochs.x=3", "expected section.key=value"),
    ],
)
def test_a_bad_variant_recipe_names_its_key(override: str, expected: str) -> None:
    with pytest.raises(ConfigError) as caught:
        load_config(None, [override])
    assert expected in str(caught.value)


def test_a_goal_variants_recipe_is_checked_as_that_variant_trains() -> None:
    """goal_residual is refused for the baseline alone, so a goal variant's recipe may set it whatever the
    profile's own variant is."""
    cfg = load_config(None, ["per_variant.re.cvae.output='goal_residual'"])
    assert cfg.cvae.variant == "baseline"
    assert variant_section(predictor_config(cfg, "re"), "cvae").output == "goal_residual"


def test_the_raw_folder_defaults_to_where_fetch_data_put_the_files(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Beside a checkout the raw files are in ../shared; elsewhere, after `fftool fetch-data`, in its folder."""
    from fftool.config import DEFAULT_RAW_DIR, FETCHED_RAW_DIR, DataConfig

    work = tmp_path / "work"
    (work / FETCHED_RAW_DIR).mkdir(parents=True)
    monkeypatch.chdir(work)
    assert DataConfig().raw_dir == FETCHED_RAW_DIR
    (tmp_path / "shared/data/eth_ucy/raw").mkdir(parents=True)
    assert DataConfig().raw_dir == DEFAULT_RAW_DIR  # the shared folder, where there is one
