"""The configuration: a TOML or JSON file of sections, then `--set section.key=value` overrides (JSON values,
else text), then a command's own options, which win; every setting range-checked, and a bad one refused in
one line naming it (exit 2) before any work."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from cli_errors import RG, cli
from faults_data import write_log

from aftershock.pipeline.config import Config, Environment, load_config
from aftershock.pipeline.errors import InputError
from aftershock.pipeline.mission import build_config


def assert_one_line(err: str, *names: object) -> None:
    """The error is the last line of stderr and names what it is about; no traceback."""
    assert "Traceback" not in err, err
    line = err.strip().splitlines()[-1]
    assert line.startswith("aftershock: error:"), err
    for name in names:
        assert str(name) in line, (name, line)


def test_defaults_then_file_then_overrides_then_options(tmp_path: Path) -> None:
    defaults = load_config(None)
    assert defaults == Config() and defaults.map.voxel_size_m > 0
    toml = tmp_path / "c.toml"
    toml.write_text("[map]\nvoxel_size_m = 0.2\n\n[source]\nevery = 3\n")
    from_file = load_config(toml)
    assert from_file.map.voxel_size_m == 0.2 and from_file.source.every == 3
    assert from_file.registration == defaults.registration  # sections not named keep their defaults
    as_json = tmp_path / "c.json"
    as_json.write_text(json.dumps({"map": {"voxel_size_m": 0.2}, "source": {"every": 3}}))
    assert load_config(as_json) == from_file
    over = load_config(toml, ["map.voxel_size_m=0.3", 'label.environment="outdoor"', "label.environment=indoor"])
    assert over.map.voxel_size_m == 0.3 and over.source.every == 3 and over.label.environment is Environment.INDOOR
    cfg = build_config(toml, ["source.every=5", "source.max_scans=7"], labeller="rule", every=2)
    assert cfg.source.every == 2 and cfg.source.max_scans == 7 and cfg.label.labeller == "rule"  # options win


@pytest.mark.parametrize(
    ("override", "named"),
    [
        ("map.voxel_size_m", "not of the form section.key=value"),
        ("voxel_size_m=0.2", "not of the form section.key=value"),
        ("map.voxel_size_m=fast", "config map.voxel_size_m"),
        ("map.no_such_key=1", "config map.no_such_key"),
    ],
)
def test_a_bad_override_is_one_error_naming_it(override: str, named: str) -> None:
    with pytest.raises(InputError, match=named):
        load_config(None, [override])


def test_a_missing_or_broken_config_file_is_named(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="config file not found"):
        load_config(tmp_path / "none.toml")
    broken = tmp_path / "broken.toml"
    broken.write_text("[map\nvoxel_size_m = 0.2\n")
    with pytest.raises(InputError, match="not a valid toml config"):
        load_config(broken)


def _numeric_settings() -> list[tuple[str, str]]:
    out = []
    for section, field in Config.model_fields.items():
        for name, info in field.annotation.model_fields.items():
            text = str(info.annotation)
            if "float" in text or "int" in text:
                out.append((section, name))
    return out


def test_every_numeric_setting_refuses_nan_and_infinity() -> None:
    settings = _numeric_settings()
    assert len(settings) > 80
    for section, name in settings:
        for bad in ("NaN", "Infinity", "-Infinity"):
            with pytest.raises(InputError, match=f"config {section}.{name}"):
                load_config(None, [f"{section}.{name}={bad}"])


@pytest.mark.parametrize(
    ("args", "named"),
    [
        (["--set", "map.voxel_size_m=0"], "map.voxel_size_m"),
        (["--set", "map.voxel_size_m=-0.1"], "map.voxel_size_m"),
        (["--set", "map.voxel_size_m=NaN"], "map.voxel_size_m"),
        (["--set", "registration.voxel_size_m=0"], "registration.voxel_size_m"),
        (["--set", "cluster.beta_indoor=2"], "cluster.beta_indoor"),
        (["--set", "rerun.map_every=0"], "rerun.map_every"),
        (["--start", "inf"], "--start"),
        (["--start", "nan"], "--start"),
        (["--start", "-3"], "--start"),
        (["--end", "inf"], "--end"),
        (["--every", "0"], "--every"),
        (["--max-scans", "-1"], "--max-scans"),
    ],
)
def test_out_of_range_settings_are_refused_in_one_line_before_any_work(args, named, tmp_path: Path, capsys) -> None:
    log = write_log(tmp_path / "log.mcap", 2)
    code, _, err = cli(["run", str(log), *RG, "-q", "--save", str(tmp_path / "x.rrd"), *args], capsys)
    assert code == 2
    assert_one_line(err, named)
    assert not (tmp_path / "x.rrd").exists()


@pytest.mark.parametrize("text", ["[1, 2, 3]", '"map"', '{"map": 3}'])
def test_a_config_that_is_no_table_is_one_line(text: str, tmp_path: Path, capsys) -> None:
    cfg = tmp_path / "c.json"
    cfg.write_text(text)
    code, _, err = cli(["run", "--config", str(cfg), "--set", "map.voxel_size_m=0.2", "-q"], capsys)
    assert code == 2
    assert_one_line(err, cfg)
