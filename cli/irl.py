"""`demo irl train`: reinforcement learning on the tasks' Gymnasium environments: PPO on the dense task
reward (or a learned one: reward transfer), residual RL on a frozen imitation run, full fine-tuning of a BC
run, GAIL and AIRL, and
linear-reward IRL (MaxEnt, apprenticeship)."""

from __future__ import annotations

from pathlib import Path

import typer

from demo import algorithms
from demo.cli.main import app, invocation
from demo.cli.options import json_option, overwrite_option, robot_option
from demo.cli.output import kv_table, report_console, write_json
from demo.cli.progress import bars
from demo.errors import DemoError
from demo.rl.config import ACTIONS, AdversarialConfig, FinetuneConfig, LinearIRLConfig, PPOConfig, ResidualConfig
from demo.store import EpisodeStore

irl_app = typer.Typer(help="Reinforcement and inverse reinforcement learning: PPO, GAIL, AIRL, MaxEnt IRL, apprenticeship.",
                      no_args_is_help=True)
app.add_typer(irl_app, name="irl")

ALGOS = algorithms.names(algorithms.IRL)
_P, _A, _L, _R, _F = PPOConfig(), AdversarialConfig(), LinearIRLConfig(), ResidualConfig(), FinetuneConfig()  # the defaults live in the library's dataclasses
FROM_SIMULATOR = ("ppo", "residual", "finetune")  # the algorithms that learn from the reward alone, without a store
FROM_RUN = ("residual", "finetune")  # the algorithms that start from an imitation run (--init), on its task and robot
# Which option sets which field (tests/rl/test_cli_options.py holds these to the dataclasses and the command).
FIELD_OPTIONS = {
    "PPOConfig": {"task": "--task", "robot": "--robot", "out": "--out", "reward": "--reward", "action": "--action",
                  "obs_keys": "--obs-keys", "seed": "--seed", "total_steps": "--steps", "num_envs": "--envs",
                  "num_steps": "--rollout", "lr": "--lr", "ent_coef": "--ent-coef", "eval_every": "--eval-every",
                  "eval_episodes": "--eval-episodes", "threads": "--threads"},
    "AdversarialConfig": {"data": "STORE", "kind": "--algo", "demos": "--demos", "inputs": "--inputs", "init": "--init",
                          "scale": "--scale", "bc_coef": "--bc-coef",
                          "disc_obs_keys": "--disc-obs-keys", "grad_penalty": "--grad-penalty", "init_bc": "--init-bc",
                          "gail_reward": "--gail-reward", "airl_reward": "--airl-reward"},
    "ResidualConfig": {"init": "--init", "scale": "--scale", "data": "STORE", "demos": "--demos", "bc_coef": "--bc-coef"},
    "FinetuneConfig": {"init": "--init", "data": "STORE", "demos": "--demos", "bc_coef": "--bc-coef",
                       "policy_lr": "--policy-lr"},
    "LinearIRLConfig": {"data": "STORE", "method": "--algo", "demos": "--demos", "inner_iterations": "--inner-iterations"},
}


@irl_app.command("train")
def train(
    store: str = typer.Argument(None, metavar="STORE", help="Demonstrations (gail, airl, maxent, apprenticeship; residual, "
                                "finetune: kept in a BC term): a store of the task in the policy's action representation.",
                                show_default=False),
    out: Path = typer.Option(..., "--out", "-o", metavar="RUN", help="Run directory to write (demo eval runs it).",
                             show_default=False),
    algo: str = typer.Option("ppo", help=f"Algorithm: {', '.join(ALGOS)}."),
    task: str = typer.Option(None, help="Task.", show_default="the store's; ppo: reach"),
    reward: str = typer.Option("task", metavar="task|RUN", help="ppo, residual, finetune: the dense task reward (demo.rl.rewards), "
                               "or the reward learned by an IRL run (maxent, apprenticeship, airl): reward transfer."),
    init: str = typer.Option(None, "--init", metavar="RUN", help="residual, gail: the imitation run to correct (its task, "
                             "options, robot and actions; it stays frozen): the policy is a residual over it. finetune: "
                             "the BC run whose own weights PPO changes.",
                             show_default="none; residual and finetune need one"),
    bc_coef: float = typer.Option(_R.bc_coef, help="residual, finetune with a STORE, gail --init: the weight of the BC "
                                  "term that keeps the demonstrations during RL."),
    policy_lr: float = typer.Option(_F.policy_lr, help="finetune: Adam's learning rate of the BC run's weights "
                                    "(annealed; the critic's is --lr)."),
    scale: float = typer.Option(_R.scale, help="residual, gail --init: the largest correction, as a fraction of each "
                                "action entry's half-range in the base run's data."),
    robot: str = robot_option(),
    action: str = typer.Option(_P.action, metavar="|".join(ACTIONS), help="The policy's actions: ee7 deltas "
                               "(through the env's IK) or joint targets relative to the measured joints."),
    obs_keys: str = typer.Option(None, help="Comma-separated obs.* keys.", show_default="state keys without velocities"),
    steps: int = typer.Option(None, help="Environment (control) steps in all.",
                              show_default=f"{_P.total_steps:,}; with --init: {_R.rl.total_steps:,}"),
    envs: int = typer.Option(_P.num_envs, help="Environments stepped in turn."),
    rollout: int = typer.Option(None, help="Control steps per environment per PPO iteration.",
                                show_default=f"{_P.num_steps}; with --init: {_R.rl.num_steps}"),
    lr: float = typer.Option(_P.lr, help="Adam learning rate of the policy and critic (annealed to 0)."),
    ent_coef: float = typer.Option(_P.ent_coef, help="Entropy bonus coefficient."),
    seed: int = typer.Option(_P.seed, help="Seed of initialisation, sampling and the training episodes."),
    demos: int = typer.Option(None, help="Use the first N successful demonstrations.", show_default="all"),
    init_bc: bool = typer.Option(_A.init_bc, "--init-bc/--no-init-bc",
                                 help="gail, airl: fit the policy's mean to the demonstrations first."),
    inputs: str = typer.Option(_A.inputs, metavar="sa|ss|s", help="gail: the discriminator reads (s, a), (s, s') or s'."),
    grad_penalty: float = typer.Option(_A.grad_penalty, help="gail, airl: gradient penalty weight."),
    gail_reward: str = typer.Option(_A.gail_reward, metavar="softplus|logit",
                                    help="gail: reward -log(1 - D) (softplus of the logit) or log D - log(1 - D) (the logit)."),
    airl_reward: str = typer.Option(_A.airl_reward, metavar="logit|f",
                                    help="airl: reward f - log pi (the paper's, entropy-regularised) or f alone."),
    disc_obs_keys: str = typer.Option(None, help="gail, airl: comma-separated obs.* keys the discriminator reads, e.g. "
                                      "obs.goal_pos-obs.ee_pos,obs.goal_quat-obs.ee_quat (the goal relative to the hand).",
                                      show_default="the task's goal relative to the hand (reach), else the policy's"),
    inner: int = typer.Option(_L.inner_iterations, "--inner-iterations", help="maxent, apprenticeship: PPO iterations per reward update."),
    eval_every: int = typer.Option(_P.eval_every, help="PPO iterations between rollout evaluations (0: at the end only)."),
    eval_episodes: int = typer.Option(_P.eval_episodes, help="Episodes per rollout evaluation (monitoring seeds)."),
    threads: int = typer.Option(_P.threads, help="Torch threads (0 = torch's default)."),
    overwrite: bool = overwrite_option("an existing run in --out"),
    json_out: str = json_option("the run summary"),
) -> None:
    """Train a policy by RL in the simulator; every run directory evaluates with demo eval RUN."""
    algorithms.algorithm(algo, algorithms.IRL)  # an unknown --algo fails here, naming the choices
    if algo == "ppo" and store is not None:
        raise DemoError("STORE", "ppo learns from the reward, not from a store")
    if algo not in FROM_SIMULATOR and store is None:
        raise DemoError("STORE", f"{algo} learns from demonstrations: name a STORE")
    if algo not in FROM_SIMULATOR and reward != "task":
        raise DemoError("--reward", f"{algo} learns its own reward; --reward applies to {' and '.join(FROM_SIMULATOR)}")
    if algo in FROM_RUN and init is None:
        raise DemoError("--init", f"{algo} starts from the imitation run --init names")
    if init is not None and algo not in (*FROM_RUN, "gail"):
        raise DemoError("--init", f"names the imitation run residual, finetune and gail start from, not a start for {algo}")
    if algo in FROM_RUN and (task or robot):
        raise DemoError("--task" if task else "--robot", f"{algo} runs on its imitation run's task and robot")
    # RL from an imitation run (residual, gail --init, finetune) has its own PPO defaults
    defaults = _F.rl if algo == "finetune" else _R.rl if init is not None else _P
    rl = PPOConfig(task=task or (_store_task(store) if store and algo not in FROM_RUN else "reach"), robot=robot,
                   out=str(out), reward=reward, action=action, obs_keys=_keys(obs_keys), seed=seed,
                   total_steps=defaults.total_steps if steps is None else steps, num_envs=envs,
                   num_steps=defaults.num_steps if rollout is None else rollout, init_log_std=defaults.init_log_std,
                   target_kl=defaults.target_kl,
                   lr=lr, ent_coef=ent_coef,
                   eval_every=eval_every, eval_episodes=eval_episodes, threads=threads)
    if algo == "ppo":
        config: PPOConfig | AdversarialConfig | LinearIRLConfig | ResidualConfig | FinetuneConfig = rl
    elif algo == "residual":
        config = ResidualConfig(rl=rl, init=init, scale=scale, data=store or "", demos=demos, bc_coef=bc_coef)
    elif algo == "finetune":
        config = FinetuneConfig(rl=rl, init=init, data=store or "", demos=demos, bc_coef=bc_coef, policy_lr=policy_lr)
    elif algo in ("gail", "airl"):
        config = AdversarialConfig(rl=rl, data=store, kind=algo, demos=demos, inputs=inputs, grad_penalty=grad_penalty,
                                   init_bc=init_bc, gail_reward=gail_reward, airl_reward=airl_reward,
                                   disc_obs_keys=_keys(disc_obs_keys), init=init or "", scale=scale, bc_coef=bc_coef)
    else:
        config = LinearIRLConfig(rl=rl, data=store, method=algo, demos=demos, inner_iterations=inner)
    with bars() as progress:
        summary = algorithms.train(algo, config, progress=progress, overwrite=overwrite, command=invocation())
    rows = [("run", summary["out"]), ("algo", algo), ("environment steps", summary["env_steps"]),
            ("eval success (monitoring seeds)", "-" if summary["success_rate"] is None else
             f"{summary['success_rate']:.0%} of {summary['eval_episodes']}"),
            ("seconds", f"{summary['seconds']:.1f}")]
    if "weights" in summary:
        for name, unit, w, wu, t in zip(summary["features"], summary["units"], summary["weights"],
                                        summary["weights_unit"], summary["true_unit"]):
            rows.append((f"weight {name} [{unit}]", f"{w:+.4g} (unit norm {wu:+.3f}; true {t:+.3f})"))
        rows.append(("cosine to the true weights", summary["cosine_to_true"]))
    for key, what in (("reward_corr", "final weights"), ("reward_corr_last5", "reward trained on, last 5 iterations"),
                      ("g_corr_last5", "AIRL g(s'), last 5 iterations")):
        if summary.get(key) is not None:
            rows.append((f"learned vs task reward (Pearson r over rollouts; {what})", summary[key]))
    report_console(json_out).print(kv_table("trained", rows))
    write_json(summary, json_out)


def _store_task(store: str) -> str:
    with EpisodeStore.open(store) as s:
        name = (s.meta.task or {}).get("name")
    if not name:
        raise DemoError(store, "records no task; pass --task")
    return str(name)


def _keys(text: str | None) -> tuple[str, ...]:
    return tuple(k.strip() for k in (text or "").split(",") if k.strip())
