"""Behaviour-cloning warm start of an absolute-mode actor (``TrainConfig.warm_start``, docs/training.md).

Why: PPO from scratch in the paper's absolute action mode learned nothing on ``tiny`` (0 successes in 2,820
episodes): the zero-mean actor sets every joint target to mid-range (the hand leaves the pre-grasp), its action
noise of 0.5 is ten times what the scripted expert survives (noise 0.05 on its actions: 16/16 -> 0/16 held), and
success needs ~190 precise control steps of 200. The warm start puts the actor near a working policy *in the same
action space*; the policy still outputs absolute joint targets and wrist motion, nothing is added to its action.

1. :func:`collect_demonstrations`: the base expert (``warm_start.expert``, scripted) drives the training env for
   ``samples`` env steps; the executed action gets Gaussian noise ``demo_noise`` (DART), the label is the expert's
   clean action (n, K + 6) in [-1, 1], exactly what an absolute-mode policy outputs.
2. :func:`fit_normalizer`: the actor's and critic's observation normalizers are set to the demonstrations' mean and
   std (floored as after the usual warm-up); the actor's is frozen there if ``freeze_actor_normalizer``.
3. :func:`behaviour_clone`: MSE between the actor's mean and the labels, Adam, shuffled mini-batches from a
   seeded generator (a CPU run repeats exactly).
4. The runner's first ``critic_iterations`` iterations fit only the critic (:func:`critic_regression`), then PPO
   starts with the action std ``init_std``; with ``anchor_steps`` each PPO update is followed by that many steps
   of the imitation loss on the same demonstrations (:func:`anchor`, as DAPG keeps a demonstration term).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import torch
from tensordict import TensorDict

from ges_core.env.success import EndReason
from ges_core.errors import ConfigError

__all__ = [
    "Demonstrations",
    "anchor",
    "behaviour_clone",
    "collect_demonstrations",
    "critic_regression",
    "demo_objects",
    "fit_normalizer",
    "imitation_loss",
    "sync_wrist_mirror",
]

STD_FLOOR = 0.1
"""Smallest std kept by a fitted normalizer, as after the runner's usual warm-up (runner.STD_FLOOR says why)."""


@dataclass
class Demonstrations:
    """Observation-label pairs of the base expert's rollouts."""

    obs: torch.Tensor
    """(N, obs size) float32 observations as the policy sees them (observation noise included)."""
    actions: torch.Tensor
    """(N, K + 6) float32 the expert's clean actions, clamped to [-1, 1] (the labels)."""
    env_steps: int
    """Control steps x envs the collection took (= N)."""
    episodes: int = 0
    successes: int = 0
    """Episodes that ended during the collection and how many of them under the paper's protocol."""
    reasons: dict[str, int] = field(default_factory=dict)

    @property
    def success_rate(self) -> float:
        return self.successes / self.episodes if self.episodes else math.nan


def demo_objects(curriculum) -> list[str]:
    """Every object of the curriculum's stages (sorted): what ``all_objects`` demonstrations draw from."""
    return sorted(set().union(*curriculum.stage_objects.values()))


def collect_demonstrations(venv, expert, samples: int, noise: float, generator: torch.Generator) -> Demonstrations:
    """Step the GraspVecEnv ``venv`` for ceil(samples / num_envs) control steps with ``expert``'s actions +
    N(0, noise) (executed, clamped); every visited observation is labelled with ``expert``'s clean action. The
    expert forgets each env's episode when it ends; before each label its wrist-target mirror is set to the env's
    target (:func:`sync_wrist_mirror`).

    The expert reads the observation with the goal blocks G. Where the policy's has none (NoGoal), the expert is a
    teacher: it reads the policy's observation with the env's exact goal put in (``GraspEnv.goal_obs``,
    ``ObservationLayout.add_goal``), and the demonstrations keep the policy's own view, so the student learns
    what it can of the teacher's actions without the goal."""
    if samples < 1:
        raise ConfigError(f"warm start: samples is {samples}; give at least 1 demonstration sample")
    n = venv.num_envs
    steps = math.ceil(samples / n)
    layout = venv.env.obs_layout
    obs = venv.get_observations()["policy"]
    expert.reset()
    all_obs, all_act = [], []
    demo = Demonstrations(torch.empty(0), torch.empty(0), steps * n)
    for _ in range(steps):
        sync_wrist_mirror(expert, venv.env)
        seen = obs if layout.goal else layout.add_goal(obs, torch.as_tensor(venv.env.goal_obs))
        label = expert.act(seen).to(torch.float32).clamp(-1.0, 1.0)
        all_obs.append(obs.clone())
        all_act.append(label)
        executed = label + noise * torch.randn(label.shape, generator=generator) if noise > 0 else label
        td, _, done, extras = venv.step(executed.clamp(-1.0, 1.0))
        obs = td["policy"]
        ended = done.nonzero().flatten()
        if len(ended):
            expert.reset(ended)
            for code in extras["end_reason"][ended].tolist():
                name = EndReason(int(code)).name.lower()
                demo.reasons[name] = demo.reasons.get(name, 0) + 1
                demo.episodes += 1
                demo.successes += int(code) == int(EndReason.SUCCESS)
    demo.obs, demo.actions = torch.cat(all_obs), torch.cat(all_act)
    return demo


def sync_wrist_mirror(expert, env) -> None:
    """Set an expert's copy of the integrated wrist target (the scripted expert's ``plan["target_pos"]``,
    ``plan["target_rot"]``, documented there) to the env's ``wrist_target`` (n, 7): steered open loop, it would
    otherwise integrate its own clean labels while the executed noisy actions (DART) move the real target, and
    label later states with steps toward a place ~1 mm off. Envs starting an episode are re-latched by the expert
    itself. No-op for an expert without such a mirror."""
    plan = getattr(expert, "plan", None)
    if not isinstance(plan, dict) or "target_pos" not in plan or plan["target_pos"].shape[0] != env.n:
        return
    target = torch.as_tensor(env.wrist_target, dtype=plan["target_pos"].dtype)
    plan["target_pos"] = target[:, :3].clone()
    plan["target_rot"] = target[:, 3:].clone()


def fit_normalizer(model, obs: torch.Tensor, freeze: bool) -> None:
    """Set ``model``'s observation normalizer (rsl-rl EmpiricalNormalization) to the mean and std of ``obs``
    (N, D), std floored at :data:`STD_FLOOR`; ``freeze``: no later update changes it. No-op without one."""
    norm = getattr(model, "obs_normalizer", None)
    if norm is None or not hasattr(norm, "_var"):
        return
    with torch.no_grad():
        norm._mean.copy_(obs.mean(dim=0, keepdim=True))
        norm._var.copy_(obs.var(dim=0, unbiased=False, keepdim=True).clamp(min=STD_FLOOR**2))
        norm._std.copy_(norm._var.sqrt())
        norm.count.fill_(obs.shape[0])
    if freeze:
        freeze_normalizer(model)


def freeze_normalizer(model) -> None:
    """Stop ``model``'s normalizer from updating (rsl-rl's ``until``: updates stop once ``count`` reaches it)."""
    norm = getattr(model, "obs_normalizer", None)
    if norm is not None and hasattr(norm, "until"):
        norm.until = int(norm.count)


def _td(obs: torch.Tensor) -> TensorDict:
    return TensorDict({"policy": obs}, batch_size=[obs.shape[0]])


def imitation_loss(actor, obs: torch.Tensor, actions: torch.Tensor) -> float:
    """Mean squared error (per action value) between the actor's mean on ``obs`` (N, D) and ``actions`` (N, A)."""
    with torch.no_grad():
        return float((actor(_td(obs)) - actions).square().mean())


def behaviour_clone(actor, demo: Demonstrations, *, epochs: int, batch_size: int, learning_rate: float,
                    generator: torch.Generator) -> list[float]:  # fmt: skip
    """Regress the actor's mean (its MLP; the normalizer and the action std stay) on the labels; returns the
    imitation loss before the first epoch and after each (epochs + 1 values)."""
    params = list(actor.mlp.parameters())
    optimizer = torch.optim.Adam(params, lr=learning_rate)
    losses = [imitation_loss(actor, demo.obs, demo.actions)]
    n = demo.obs.shape[0]
    for _ in range(epochs):
        order = torch.randperm(n, generator=generator)
        for start in range(0, n, batch_size):
            idx = order[start : start + batch_size]
            loss = (actor(_td(demo.obs[idx])) - demo.actions[idx]).square().mean()
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
        losses.append(imitation_loss(actor, demo.obs, demo.actions))
    return losses


def anchor(actor, demo: Demonstrations, optimizer: torch.optim.Optimizer, steps: int, batch_size: int,
           generator: torch.Generator) -> float:  # fmt: skip
    """``steps`` Adam steps of the imitation loss on random mini-batches of ``demo`` (the actor's MLP only);
    the mean loss over them."""
    total = 0.0
    n = demo.obs.shape[0]
    for _ in range(steps):
        idx = torch.randint(n, (min(batch_size, n),), generator=generator)
        loss = (actor(_td(demo.obs[idx])) - demo.actions[idx]).square().mean()
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        total += float(loss.detach())
    return total / max(steps, 1)


def critic_regression(critic, storage, optimizer: torch.optim.Optimizer, epochs: int, mini_batches: int,
                      max_grad_norm: float) -> float:  # fmt: skip
    """One critic-only update on a filled rsl-rl rollout storage (returns computed): unclipped MSE of the value
    on the returns over ``epochs`` x ``mini_batches``; the mean value loss. The actor is not touched."""
    total, count = 0.0, 0
    for batch in storage.mini_batch_generator(mini_batches, epochs):
        values = critic(batch.observations)
        loss = (values - batch.returns).square().mean()
        optimizer.zero_grad()
        loss.backward()
        torch.nn.utils.clip_grad_norm_(critic.parameters(), max_grad_norm)
        optimizer.step()
        total, count = total + float(loss.detach()), count + 1
    return total / max(count, 1)
