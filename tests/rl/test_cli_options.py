"""`demo irl train`'s options take their defaults from the RL configuration dataclasses: a test fails when
an option and the field it sets disagree, or an option names a field that does not exist."""

from __future__ import annotations

import dataclasses

from demo import algorithms
from demo.cli import irl as cli_irl
from demo.cli.main import commands
from demo.rl.config import AdversarialConfig, FinetuneConfig, LinearIRLConfig, PPOConfig, ResidualConfig

CONFIGS = {c.__name__: c for c in (PPOConfig, AdversarialConfig, LinearIRLConfig, ResidualConfig, FinetuneConfig)}


def test_every_mapped_option_exists_and_has_the_fields_default() -> None:
    command = commands()["irl train"]
    options = {opt: p for p in command.params for opt in p.opts}
    for name, mapping in cli_irl.FIELD_OPTIONS.items():
        config = CONFIGS[name]()
        fields = {f.name for f in dataclasses.fields(config)}
        for field, flag in mapping.items():
            assert field in fields, f"{name} has no field {field}"
            if flag == "STORE":
                continue
            assert flag in options, f"demo irl train has no {flag}"
            default = getattr(config, field)
            if flag in ("--algo", "--task", "--obs-keys", "--disc-obs-keys", "--robot", "--out", "--init"):
                continue  # chosen per run (the algorithm, the store's task, parsed key lists, paths)
            if flag in ("--steps", "--rollout"):  # per algorithm: None takes PPO's or the residual's default
                assert options[flag].default is None, flag
                continue
            assert options[flag].default == default, f"{flag}: {options[flag].default!r} != {name}.{field} = {default!r}"


def test_the_algorithm_choices_are_the_registrys() -> None:
    assert cli_irl.ALGOS == algorithms.names(algorithms.IRL)
    for name in cli_irl.ALGOS:
        assert algorithms.ALGORITHMS[name].config.__name__ in CONFIGS
