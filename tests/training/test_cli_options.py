"""`demo train`'s options and the configuration dataclasses are one source: a field with a help text is an
option (generated), every other field is set by a named argument, and nothing else is configuration."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import typer
from typer.testing import CliRunner

from demo.cli import train as cli_train
from demo.cli.config_options import config_options, flag_of, option_fields, with_options
from demo.cli.main import commands
from demo.imitation.config import DaggerConfig
from demo.training.config import LOOP_DEFAULTS, RESUME_KEYS, TrainConfig, setting

# Options that steer the command, not the configuration (where it runs, what it does with the result), and
# the encoder options (--crop, --color-jitter, --aux-weight: fields of EncoderConfig, not of TrainConfig).
CONTROLS = {"--head", "--crop", "--color-jitter", "--aux-weight", "--algo-opt", "--workers", "--executor", "--address", "--resume", "--overwrite", "--json",
            "--nproc", "--distil", "--help"}


def train_options() -> dict[str, object]:
    command = commands()["train"]
    return {opt: p for p in command.params for opt in p.opts if opt.startswith("--")}


def test_every_field_is_an_option_or_set_by_a_named_argument() -> None:
    for config in (TrainConfig, DaggerConfig):
        generated = {f.name for f in option_fields(config)}
        for f in dataclasses.fields(config):
            assert (f.name in generated) != (f.name in cli_train.SET_BY_ARGUMENTS), \
                f"{config.__name__}.{f.name}: an option (help text) or set by an argument, exactly one"


def test_every_generated_option_exists_with_the_fields_default() -> None:
    options = train_options()
    for config in (TrainConfig, DaggerConfig):
        for f in option_fields(config):
            flag = flag_of(f)
            assert flag in options, f"demo train has no {flag} for {config.__name__}.{f.name}"
            assert options[flag].default == f.default, f"{flag}: default {options[flag].default!r} != {f.default!r}"


def test_nothing_else_is_an_option() -> None:
    fields = {flag_of(f) for c in (TrainConfig, DaggerConfig) for f in option_fields(c)}
    named = set(cli_train.SET_BY_ARGUMENTS.values()) - {"STORES"}
    extra = set(train_options()) - fields - named - CONTROLS
    assert not extra, f"demo train options that are neither a config field nor a control: {sorted(extra)}"
    assert named <= set(train_options())


def test_tuned_settings_show_each_policys_default() -> None:
    for f in option_fields(TrainConfig):
        if f.name in LOOP_DEFAULTS:
            assert f.default is None, f"{f.name} is tuned per policy: None until resolved"
    help_text = CliRunner().invoke(cli_train.app, ["train", "--help"], env={"COLUMNS": "200"}).output
    assert "diffusion 16000" in help_text and "act 64" in help_text


def test_resume_keys_come_from_the_fields() -> None:
    assert "lr" in RESUME_KEYS and "policy" in RESUME_KEYS
    assert "steps" not in RESUME_KEYS and "device" not in RESUME_KEYS and "data" not in RESUME_KEYS


def test_a_new_setting_is_one_edit() -> None:
    """A field declared with a help text becomes an option with its flag, type, default and help."""

    @dataclass
    class Config:
        plain: int = 3
        horizon: int | None = setting(None, "Steps per episode.", unset="the task's")
        jitter: float = setting(0.5, "Std of the jitter.", flag="--noise")
        shuffle: bool = setting(False, "Shuffle.")

    app = typer.Typer()

    @app.command()
    @with_options("name", config_options(Config))
    def run(name: str = typer.Option("x"), **settings: object) -> None:
        print(sorted(settings.items()))

    runner = CliRunner()
    out = runner.invoke(app, ["--horizon", "7", "--noise", "0.25", "--shuffle"]).output
    assert out.strip() == "[('horizon', 7), ('jitter', 0.25), ('shuffle', True)]"
    assert runner.invoke(app, []).output.strip() == "[('horizon', None), ('jitter', 0.5), ('shuffle', False)]"
    shown = runner.invoke(app, ["--help"], env={"COLUMNS": "200"}).output
    assert "Steps per episode." in shown and "the task's" in shown and "--plain" not in shown
