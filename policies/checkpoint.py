"""Run directories: everything needed to run, evaluate and resume a trained policy, in safe formats.

::

    RUN/
      run.json             what was trained and how: algo, policy config and shapes, observation keys,
                           action representation, execution (chunking), task, robot, data, training
                           config, the exact command, versions
      policy.safetensors   weights used for evaluation (the EMA weights when EMA is on) + normalisers
      train_state.pt       for --resume: raw and EMA weights, optimiser, schedule, step, RNG states;
                           plain tensors and containers only, read with torch.load(weights_only=True)
      metrics.json         loss and success curves, final figures
      curves.png           the same as a plot
      robot/               the robot's MJCF and asset files (a non-built-in robot; see save_robot)
      robots/<i>/robot/    a union's other robots' files (run.json "robots"[i], i >= 1; see robot_home)

No file is ever unpickled: ``policy.safetensors`` is read by safetensors (a pickle is not a valid
file), ``train_state.pt`` by ``torch.load(weights_only=True)``, whose restricted unpickler refuses
any global it does not know (a pickle bomb fails before running code). Every file is written to a
temporary name and renamed, so an interrupted save never leaves a half-written checkpoint.
"""

from __future__ import annotations

import json
import math
import pickle
import re
import time
import warnings
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from safetensors import SafetensorError
from safetensors.torch import load_file, save_file

from demo.errors import DemoError, first_line
from demo.jsonio import replace_atomically, write_json
from demo.sim.robot_record import resolve_robot, robot_record
from demo.store import ActionSpec
from demo.store.robot_files import copy_robot_files, file_table, same_robot
from demo.policies.actor import ExecConfig, PolicyActor
from demo.policies.instruction import InstructionTokenizer, text_record
from demo.policies.normalizer import MinMaxNormalizer
from demo.policies.observation import ObsSpec
from demo.policies.policy import Policy, PolicySpec, build_policy, config_to_json, policy_config
from demo.policies.prefix import unwrapped
from demo.policies.relative import RelativeActions
from demo.policies.residual import Residual, load_residual
from demo.policies.visuomotor import encoder_record

RUN_FORMAT = "demo-run"
RUN_VERSION = 1
RUN_FILE = "run.json"
POLICY_FILE = "policy.safetensors"
STATE_FILE = "train_state.pt"
METRICS_FILE = "metrics.json"
CURVES_FILE = "curves.png"
ROBOTS_DIR = "robots"


@dataclass
class PolicyBundle:
    """A policy with everything needed to run it."""

    algo: str
    policy: Policy
    obs_spec: ObsSpec
    obs_norm: MinMaxNormalizer
    action_norm: MinMaxNormalizer
    action: ActionSpec
    execution: ExecConfig
    run: dict[str, Any]  # the whole run.json (task, robot, data, training config, ...)
    path: Path | None = None
    relative: RelativeActions | None = None
    tokenizer: InstructionTokenizer | None = None  # an instruction-conditioned policy's (demo.policies.instruction)
    residual: Residual | None = None  # a correction trained by RL on top of the policy (demo.policies.residual)

    @property
    def task(self) -> dict[str, Any]:
        return self.run.get("task") or {}

    @property
    def robot(self) -> dict[str, Any]:
        return self.run.get("robot") or {}

    def actor(self, execution: ExecConfig | None = None, adapter: Any = None) -> PolicyActor:
        return PolicyActor(self.policy, self.obs_spec, self.obs_norm, self.action_norm, execution or self.execution,
                           adapter, self.relative, self.tokenizer, self.residual)


def policy_record(
    algo: str, policy: Policy, obs_spec: ObsSpec, action: ActionSpec, execution: ExecConfig,
    relative: RelativeActions | None = None, tokenizer: InstructionTokenizer | None = None,
) -> dict[str, Any]:
    """The part of run.json that rebuilds the policy."""
    base = unwrapped(policy)  # behind a committed prefix's wrapper
    encoder, text = encoder_record(getattr(base, "inner", base)), text_record(base)
    return {
        "algo": algo,
        "config": config_to_json(policy.config),
        **({"encoder": encoder} if encoder else {}),
        **({"text": text, "instruction": tokenizer.to_json()} if text and tokenizer is not None else {}),
        "spec": policy.spec.to_json(),
        "obs": obs_spec.to_json(),
        "action": action.to_json(),
        "relative_actions": relative.to_json() if relative is not None else None,
        "execution": execution.to_json(),
    }


def read_json(path: str | Path) -> dict[str, Any]:
    path = Path(path)
    try:
        return json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise DemoError(path, f"unreadable ({exc})") from None


def write_run(run_dir: str | Path, run: dict[str, Any]) -> None:
    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    write_json(run_dir / RUN_FILE, {"format": RUN_FORMAT, "version": RUN_VERSION, **run})


def read_run(run_dir: str | Path) -> dict[str, Any]:
    run_dir = Path(run_dir)
    path = run_dir / RUN_FILE
    if not run_dir.exists():
        raise DemoError(run_dir, "no such run directory")
    if not path.is_file():
        raise DemoError(run_dir, f"not a training run (no {RUN_FILE})")
    try:
        run = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise DemoError(path, f"unreadable ({exc})") from None
    if not isinstance(run, dict) or run.get("format") != RUN_FORMAT:
        raise DemoError(path, f"not a demo run file (format is not {RUN_FORMAT!r})")
    if run.get("version") != RUN_VERSION:
        raise DemoError(path, f"run format version {run.get('version')!r} is not supported (this demo reads {RUN_VERSION})")
    if "policy" not in run:
        raise DemoError(path, "has no trained policy yet")
    _check_sections(run, path)
    return run


# What a run record's sections must be, for the code that reads them (eval, resume, dagger).
_SECTIONS: dict[str, tuple[type, ...]] = {"policy": (dict,), "task": (dict,), "robot": (dict, type(None)),
                                          "robots": (list,), "data": (dict, type(None)), "train": (dict, type(None))}


# Counts of a run record (the chunk, the observation history, ...): whole numbers from 1 to MAX_COUNT.
# Read with int(), 1e9 or 2.7 would pass as given.
MAX_COUNT = 10_000
_COUNTS: tuple[tuple[str, ...], ...] = (
    ("policy", "spec", "horizon"), ("policy", "spec", "n_obs"), ("policy", "execution", "execute"),
    ("policy", "execution", "candidates"), ("train", "chunk"), ("train", "n_obs"), ("train", "execute"),
    ("train", "candidates"),
)


def _check_sections(run: dict[str, Any], path: Path) -> None:
    """A run directory is untrusted: each section is of its kind before anything reads into it."""
    for key, kinds in _SECTIONS.items():
        if key in run and not isinstance(run[key], kinds):
            raise DemoError(path, f"'{key}' is a {type(run[key]).__name__}, not a JSON object")
    counts: dict[str, int] = {}
    for keys in _COUNTS:
        section = run
        for key in keys[:-1]:  # a section that is no object is the reader's to refuse
            section = section.get(key) if isinstance(section, dict) else None
        value = section.get(keys[-1]) if isinstance(section, dict) else None
        if value is None:  # absent (the reader's default), or a training setting left to its default
            continue
        name = ".".join(keys)
        if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= MAX_COUNT:
            raise DemoError(path, f"'{name}' must be a whole number from 1 to {MAX_COUNT:_}, got {value!r}")
        counts[name] = value
    for execute, chunk in (("policy.execution.execute", "policy.spec.horizon"), ("train.execute", "train.chunk")):
        if execute in counts and chunk in counts and counts[execute] > counts[chunk]:
            raise DemoError(path, f"'{execute}' ({counts[execute]}) exceeds the chunk '{chunk}' ({counts[chunk]})")
    task = run.get("task") or {}
    if not isinstance(task.get("name", ""), str) or not isinstance(task.get("options") or {}, dict):
        raise DemoError(path, "'task' must name the task (a string) and its options (an object)")
    if not all(isinstance(r, dict) for r in run.get("robots", [])):
        raise DemoError(path, "'robots' must be a list of robot records (JSON objects)")
    seeds = (run.get("data") or {}).get("seeds", [])
    if not isinstance(seeds, list) or not all(isinstance(s, int) and not isinstance(s, bool) for s in seeds):
        raise DemoError(path, "'data.seeds' must be a list of integers")


def run_robot(record: dict[str, Any] | None, store_path: str | Path, override: str | Path | None = None) -> dict[str, Any] | None:
    """The robot record a run trained on the store at ``store_path`` keeps (``run.json["robot"]``).

    ``record``: the store's ``meta.robot``; ``override``: a robot config (``--robot``) that replaces
    it. A store that records robot files which cannot be found fails here, before anything is
    written, with one line naming the missing file; the built-in arm and records without files pass.
    """
    if override is not None:
        return robot_record(resolve_robot(record, override))
    if file_table(record, store_path):
        resolve_robot(record, where=store_path)
    return record


def save_robot(run_dir: str | Path, record: dict[str, Any] | None, store_path: str | Path) -> None:
    """Copy the robot's files (of :func:`run_robot`'s ``record``) into ``run_dir/robot/`` (staged,
    then renamed) so that the run alone evaluates after it is moved."""
    Path(run_dir).mkdir(parents=True, exist_ok=True)
    copy_robot_files(record, store_path, run_dir)


def distinct_robots(records: list[dict[str, Any] | None]) -> tuple[list[dict[str, Any]], list[int]]:
    """The different robots among the records of several stores (by content, in first-seen order)
    and, per store, the index of its robot among them."""

    robots: list[dict[str, Any]] = []
    index = []
    for record in records:
        found = next((i for i, r in enumerate(robots) if same_robot(r, record)), None)
        if found is None:
            robots.append(record or {})
            found = len(robots) - 1
        index.append(found)
    return robots, index


def trained_robots(run: dict[str, Any]) -> list[dict[str, Any]]:
    """Every robot a run was trained on (a union's ``robots``, else its one ``robot``); the first is the default."""
    return list(run.get("robots") or [run.get("robot") or {}])


def robot_home(run_dir: str | Path | None, index: int) -> Path | None:
    """The folder whose ``robot/`` holds the files of the run's ``index``-th robot: the run directory
    for the first, ``robots/<index>/`` for a union's others."""
    if run_dir is None:
        return None
    return Path(run_dir) if index == 0 else Path(run_dir) / ROBOTS_DIR / str(index)


def save_policy(
    run_dir: str | Path, weights: dict[str, torch.Tensor], obs_norm: MinMaxNormalizer, action_norm: MinMaxNormalizer,
    extra: dict[str, torch.Tensor] | None = None,
) -> None:
    """Write the evaluation weights and the normalisers (and ``extra`` tensors, e.g. a residual's, under
    their own names) to ``policy.safetensors``."""
    tensors = {**policy_tensors(weights, obs_norm, action_norm), **(extra or {})}
    _write(Path(run_dir) / POLICY_FILE, lambda tmp: save_file(tensors, str(tmp), metadata={"format": RUN_FORMAT}))


def _write(path: Path, write: Any) -> None:
    """:func:`replace_atomically`, with a failed write (a full disk: torch reports it as a RuntimeError) named
    by its file in one line; the file before it stays as it was."""
    try:
        replace_atomically(path, write)
    except (OSError, RuntimeError, SafetensorError) as exc:
        raise DemoError(path, f"could not be written ({first_line(exc)}); is the disk full? The previous "
                              "checkpoint is kept") from None


def policy_tensors(weights: dict[str, torch.Tensor], obs_norm: MinMaxNormalizer,
                   action_norm: MinMaxNormalizer) -> dict[str, torch.Tensor]:
    """What ``policy.safetensors`` holds: the evaluation weights (on the CPU) and the normalisers."""
    tensors = {f"policy.{k}": v.detach().cpu().contiguous().clone() for k, v in weights.items()}
    tensors.update(obs_norm.state_dict("normalizer.obs"))
    tensors.update(action_norm.state_dict("normalizer.action"))
    return tensors


def load_bundle(run_dir: str | Path, device: torch.device | str = "cpu") -> PolicyBundle:
    """Rebuild the policy of a run directory on ``device`` (read-only; never unpickles)."""
    run_dir = Path(run_dir)
    run = read_run(run_dir)
    parts = _policy_parts(run, run_dir / RUN_FILE)
    path = run_dir / POLICY_FILE
    if not path.is_file():
        resumable = (run_dir / STATE_FILE).is_file()  # a run killed between its periodic train-state saves
        raise DemoError(run_dir, f"has no {POLICY_FILE}: training stopped before saving a policy"
                                 + (" (continue it with demo train --resume)" if resumable else ""))
    try:
        tensors = load_file(str(path))
    except (SafetensorError, OSError, ValueError) as exc:
        raise DemoError(path, f"not a valid safetensors file, refusing to load it ({str(exc).splitlines()[0][:120]})") from None
    return _assemble(run, parts, tensors, device, path, run_dir)


def bundle_from_tensors(run: dict[str, Any], tensors: dict[str, torch.Tensor], device: torch.device | str = "cpu",
                        where: str = "policy") -> PolicyBundle:
    """A policy from a run record (``run.json``'s content) and its :func:`policy_tensors` held in memory,
    e.g. a learner sent to rollout workers; checked as :func:`load_bundle` checks a run directory."""
    return _assemble(run, _policy_parts(run, where), tensors, device, where, None)


def _policy_parts(run: dict[str, Any], where: str | Path) -> tuple[Any, ...]:
    """The policy record of ``run`` parsed and checked, with the weight shapes it implies."""
    rec = run["policy"]
    try:
        spec = PolicySpec.from_json(rec["spec"])
        obs_spec = ObsSpec.from_json(rec["obs"])
        action = ActionSpec.from_json(rec["action"])
        execution = ExecConfig.from_json(rec.get("execution") or {})
        config = policy_config(rec["algo"], rec.get("config") or {})
        encoder, text = rec.get("encoder"), rec.get("text")
        relative = RelativeActions.from_json(rec.get("relative_actions"))
        tokenizer = InstructionTokenizer.from_json(rec["instruction"]) if spec.vocab else None
        _check_record(obs_spec, spec, action, relative, execution, tokenizer)
        with torch.device("meta"):  # shapes only: a record naming a huge network allocates nothing here
            shapes = {k: tuple(v.shape) for k, v in build_policy(rec["algo"], spec, config, encoder, text).state_dict().items()}
    except (KeyError, TypeError, ValueError, AttributeError, IndexError, OverflowError, RuntimeError) as exc:
        raise DemoError(where, f"malformed policy record ({exc})") from None
    return rec["algo"], spec, obs_spec, action, execution, config, (encoder, text, tokenizer), relative, shapes


def _assemble(run: dict[str, Any], parts: tuple[Any, ...], tensors: dict[str, torch.Tensor], device: torch.device | str,
              path: str | Path, run_dir: Path | None) -> PolicyBundle:
    """The bundle of parsed record ``parts`` with the weights and normalisers in ``tensors`` (from ``path``)."""
    algo, spec, obs_spec, action, execution, config, (encoder, text, tokenizer), relative, shapes = parts
    weights = {k[len("policy."):]: v for k, v in tensors.items() if k.startswith("policy.")}
    stored = {k: tuple(v.shape) for k, v in weights.items()}
    if stored != shapes:
        differ = sorted(k for k in shapes.keys() | stored.keys() if shapes.get(k) != stored.get(k))
        raise DemoError(path, f"does not match the policy in {RUN_FILE} (tensor {differ[0]}: "
                              f"{stored.get(differ[0])} in the file, {shapes.get(differ[0])} in the record)")
    policy = build_policy(algo, spec, config, encoder, text)
    try:
        policy.load_state_dict(weights, strict=True)
        obs_norm = MinMaxNormalizer.from_state_dict(tensors, "normalizer.obs")
        action_norm = MinMaxNormalizer.from_state_dict(tensors, "normalizer.action")
    except (RuntimeError, KeyError, ValueError) as exc:  # ValueError: a normaliser range a flipped bit inverted
        raise DemoError(path, f"does not match the policy in {RUN_FILE} ({str(exc).splitlines()[0][:160]})") from None
    if obs_norm.dim != obs_spec.dim or action_norm.dim != action.dim:
        raise DemoError(path, "normaliser sizes do not match the policy's observation/action sizes")
    policy.to(device).eval()
    residual = None
    if run.get("residual") is not None:
        try:
            residual = load_residual(run["residual"], tensors, action.dim)
        except (KeyError, TypeError, ValueError, RuntimeError) as exc:
            raise DemoError(path, f"does not match the residual in {RUN_FILE} ({str(exc).splitlines()[0][:160]})") from None
    return PolicyBundle(algo, policy, obs_spec, obs_norm, action_norm, action, execution, run, run_dir, relative, tokenizer,
                        residual)


def _check_record(obs: ObsSpec, spec: PolicySpec, action: ActionSpec, relative: RelativeActions | None,
                  execution: ExecConfig, tokenizer: InstructionTokenizer | None = None) -> None:
    """The parts of a policy record must agree (ValueError otherwise): a run directory is untrusted."""
    if tokenizer is not None and (tokenizer.vocab_size, tokenizer.max_tokens) != (spec.vocab, spec.max_tokens):
        raise ValueError(f"the instruction tokenizer ({tokenizer.vocab_size} words, {tokenizer.max_tokens} tokens) does "
                         f"not match the policy's spec ({spec.vocab}, {spec.max_tokens})")
    if not all(isinstance(k, str) for k in obs.keys) or len(obs.dims) != len(obs.keys) or min(obs.dims, default=0) < 0:
        raise ValueError("observation keys and dims do not pair up")
    if obs.dim != spec.obs_dim or action.dim != spec.action_dim or min(spec.n_obs, spec.horizon) < 1:
        raise ValueError(f"spec {spec} does not match the observation ({obs.dim}) and action ({action.dim}) sizes")
    if [(k, h, w) for k, (h, w, _) in zip(obs.images, obs.image_shapes)] != list(spec.images):
        raise ValueError("the policy's camera images do not match the observation's")
    if relative is not None and (relative.obs_key not in obs.keys or len(relative.obs_dims) != len(relative.action_dims)
                                 or not all(0 <= i < action.dim for i in relative.action_dims)
                                 or not all(0 <= i < obs.dims[obs.keys.index(relative.obs_key)] for i in relative.obs_dims)):
        raise ValueError("relative_actions names dims the observation or action does not have")
    if execution.ensemble is not None and not math.isfinite(execution.ensemble):
        raise ValueError("execution ensemble is not a finite number")


def save_train_state(run_dir: str | Path, state: dict[str, Any]) -> None:
    """Write the resume state (tensors, numbers, strings, lists and dicts only)."""
    _write(Path(run_dir) / STATE_FILE, lambda tmp: torch.save(state, tmp))


def load_train_state(run_dir: str | Path) -> dict[str, Any]:
    """Read the resume state with ``torch.load(weights_only=True)``; refuse anything else, saying
    what the file is (empty, truncated, not a torch checkpoint, a pickle of Python objects)."""
    path = Path(run_dir) / STATE_FILE
    if not path.is_file():
        raise DemoError(run_dir, f"has no {STATE_FILE} to resume from")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # torch's note on the pickle protocol of foreign files
            state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # noqa: BLE001 - torch raises many types on a damaged file; each is described
        raise DemoError(path, _state_problem(path, exc)) from None
    if not isinstance(state, dict) or "step" not in state:
        raise DemoError(path, "not a demo training state (no 'step')")
    return state


_ZIP_MAGIC = b"PK\x03\x04"  # torch.save's default format is a zip archive holding data.pkl + tensors
_PICKLE_HEADS = tuple(bytes([0x80, protocol]) for protocol in range(2, 6))  # PROTO opcode, protocols 2-5
_REFUSED_GLOBAL = re.compile(r"GLOBAL ([\w.]+)")


def _state_problem(path: Path, exc: BaseException) -> str:
    """What is wrong with a ``train_state.pt`` torch could not load, from what the file holds."""
    size = path.stat().st_size
    with open(path, "rb") as f:
        head = f.read(4)
    found = _REFUSED_GLOBAL.search(str(exc)) if isinstance(exc, pickle.UnpicklingError) else None
    if found:
        return (f"refusing to load: it holds Python objects ({found.group(1)}) other than tensors and plain "
                "containers (a pickle can run code)")
    if isinstance(exc, pickle.UnpicklingError) and head.startswith(_PICKLE_HEADS):
        return "refusing to load: a plain Python pickle, not a torch checkpoint (a pickle can run code)"
    if size == 0:
        return "empty file (0 bytes): not a checkpoint"
    if head.startswith(_ZIP_MAGIC):
        try:
            with zipfile.ZipFile(path) as archive:
                bad = archive.testzip()
        except (zipfile.BadZipFile, OSError, EOFError, ValueError) as zexc:
            return f"truncated or corrupted: its zip archive does not read ({first_line(zexc, 160)}; {size} bytes)"
        if bad is not None:
            return f"corrupted: archive member {bad} fails its checksum"
        return f"a zip archive that is not a torch checkpoint ({first_line(exc, 160)})"
    if head.startswith(_PICKLE_HEADS):
        return f"truncated or corrupted legacy torch checkpoint ({first_line(exc, 160)})"
    return f"not a torch checkpoint: neither a zip archive nor a pickle (starts with bytes {head.hex(' ')})"


def now() -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
