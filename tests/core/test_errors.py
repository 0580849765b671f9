"""DemoError: the message format and the trip through pickle (errors raised in worker processes)."""

import pickle

from demo.errors import DemoError


def test_message_names_the_file() -> None:
    assert str(DemoError("robot.toml", "no joint 'j9'")) == "robot.toml: no joint 'j9'"
    assert str(DemoError(None, "bad")) == "bad"


def test_survives_pickle() -> None:
    err = pickle.loads(pickle.dumps(DemoError("a.zarr", "is truncated", exit_code=3)))
    assert (err.where, err.problem, err.exit_code, str(err)) == ("a.zarr", "is truncated", 3, "a.zarr: is truncated")
