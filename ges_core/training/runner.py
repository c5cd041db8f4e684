"""rsl-rl's ``OnPolicyRunner`` with what a GES run adds: curriculum, episode counts, atomic checkpoints, resume.

:class:`GraspRunner.learn` is the runner's own loop (collect ``num_steps_per_env`` steps with ``alg.act`` /
``env.step`` / ``alg.process_env_step``, ``alg.compute_returns``, ``alg.update``, ``logger.log``) with, per
iteration: the outcomes of the episodes that ended counted per episode (both success protocols, end reasons, NaN
actions) and fed to the curriculum, whose promotions set the pool's weights and are logged; one line of
``history.jsonl`` (the success curve); a checkpoint every ``checkpoint_interval`` iterations and at the end;
the wall-time limit; with ``evaluation.interval``, before the first iteration and every that many iterations an
in-run evaluation of the noise-free policy (:mod:`ges_core.training.evaluation`: ``evaluations.jsonl``, the
curriculum's evaluation rule, a checkpoint, ``checkpoints/best.pt``). The first iteration is preceded by a
normalizer warm-up. An update that leaves a non-finite weight is undone (the weights from before it are
restored) and counted, so a diverging step does not end the run.

Iterations are counted as *done*: a checkpoint's ``iter`` is the number of iterations behind it, and a resumed
run starts at that number (rsl-rl's own loop re-runs the last index).
"""

from __future__ import annotations

import contextlib
import copy
import io
import json
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from rsl_rl.runners import OnPolicyRunner

from ges_core.env.success import EndReason
from ges_core.training.checkpoint import FORMAT, VERSION, write_checkpoint
from ges_core.training.evaluation import describe_evaluation

__all__ = ["BEST", "EpisodeCounts", "GraspRunner", "trim_run_logs"]

_SUCCESS = int(EndReason.SUCCESS)


@dataclass
class EpisodeCounts:
    """Outcomes of the episodes that ended during one iteration (counted per episode, not per step)."""

    episodes: int = 0
    paper: int = 0
    peers: int = 0
    reasons: dict[str, int] = field(default_factory=dict)
    nan_actions: int = 0
    """Env steps whose action row held NaN or inf (each ended its episode ``unstable``)."""
    per_object: dict[str, list[int]] = field(default_factory=dict)
    """object id -> [episodes, paper successes]."""
    outcomes: list[bool] = field(default_factory=list)
    """Per ended episode, in order: success under the curriculum's protocol."""

    def add(self, done: torch.Tensor, extras: dict, keys: tuple[str, ...], protocol: str) -> None:
        """Count the episodes that ended this step (``done`` (n,)); ``keys``: pool entry -> object id."""
        self.nan_actions += int(extras["log"].get("/faults/nan_actions", 0))
        ended = done.nonzero().flatten()
        if not len(ended):
            return
        reason = extras["end_reason"][ended].numpy()
        peers = extras["peer_success"][ended].numpy()
        entries = extras["entry"][ended].numpy()
        for code, peer, entry in zip(reason.tolist(), peers.tolist(), entries.tolist(), strict=True):
            paper = code == _SUCCESS
            name = EndReason(code).name.lower()
            self.reasons[name] = self.reasons.get(name, 0) + 1
            self.episodes, self.paper, self.peers = self.episodes + 1, self.paper + paper, self.peers + bool(peer)
            obj = keys[entry] if entry >= 0 else "?"
            row = self.per_object.setdefault(obj, [0, 0])
            row[0], row[1] = row[0] + 1, row[1] + paper
            self.outcomes.append(paper if protocol == "paper" else bool(peer))

    def rate(self, which: str) -> float:
        """Success rate under ``which`` ('paper' or 'peers'); NaN when no episode ended."""
        return getattr(self, which) / self.episodes if self.episodes else math.nan


class GraspRunner(OnPolicyRunner):
    """OnPolicyRunner over a GraspVecEnv (or ResidualVecEnv) with a curriculum and GES checkpoints (module docs)."""

    def __init__(self, env, train_cfg: dict, run_dir: Path, *, curriculum, meta: dict, settings,
                 demonstrator=None) -> None:  # fmt: skip
        """run_dir: the run folder (logs/, checkpoints/, history.jsonl); meta: the checkpoint's fixed ``ges``
        fields (made_for, model, ...); settings: the TrainConfig (checkpoint interval, time limit, warm-up);
        demonstrator: the Expert the behaviour-cloning warm start imitates (None: no warm start)."""
        self.run_dir, self.curriculum, self.meta, self.settings = Path(run_dir), curriculum, meta, settings
        self.demonstrator = demonstrator
        self.critic_iterations = (settings.warm_start.critic_iterations if demonstrator is not None
                                  else settings.ppo.critic_warmup_iterations)  # fmt: skip
        """The first iterations (absolute numbers) update only the critic (warm start, step 4; or
        ``ppo.critic_warmup_iterations`` without one)."""
        self._critic_optimizer: torch.optim.Optimizer | None = None
        """The critic's own Adam (critic-only iterations and ``ppo.critic_fit_epochs``); not in checkpoints: a
        resumed run starts it anew."""
        self._anchor_optimizer: torch.optim.Optimizer | None = None
        self.demonstrations = None
        """The warm start's Demonstrations (kept for the anchor steps; not in checkpoints: a resumed run has none)."""
        with contextlib.redirect_stdout(io.StringIO()):  # it prints both models; the summary says what ran
            super().__init__(env, train_cfg, log_dir=str(self.run_dir / "logs"), device="cpu")
        self.logger.git_status_repos = []  # else its logger runs git on the repository holding rsl_rl
        self.pool = env.env.pool
        self.totals = {"episodes": 0, "paper": 0, "peers": 0, "nan_actions": 0, "bad_updates": 0, "env_steps": 0}
        self.seconds = 0.0
        self.warmed = False
        self.last_counts = EpisodeCounts()
        self.on_iteration: Callable[[int, dict], None] | None = None
        """Called after every iteration with (iterations done, the history row): the progress bar."""
        self.on_promotion: Callable[[str], None] | None = None
        self.evaluator = None
        """An :class:`~ges_core.training.evaluation.InRunEvaluator` when ``evaluation.interval`` > 0 (set by the
        caller)."""
        self.evaluation = {"last": None, "best": None, "best_iteration": None, "start": None}
        """Paper-protocol success of the latest and the best in-run evaluation (over all its objects), the
        iterations behind the best, and the starting policy's per-object rows (iteration 0's ``per_object``; later
        evaluations are compared with it). Checkpointed: a resumed run keeps comparing against them."""
        self.on_evaluation: Callable[[str], None] | None = None
        """Called with one line after each in-run evaluation."""
        self._evaluated = False
        self._new_best = False

    # -- the loop --------------------------------------------------------------------------------
    def learn(self, num_learning_iterations: int, init_at_random_ep_len: bool = False) -> str:
        """Run up to ``num_learning_iterations`` more iterations; returns why it stopped ('done' or 'time_limit')."""
        if self.logger.writer is None:
            with contextlib.redirect_stdout(io.StringIO()):
                self.logger.init_logging_writer()
        obs = self.env.get_observations()
        self.alg.train_mode()
        began = time.perf_counter() - self.seconds  # the warm-up counts toward the time limit
        if not self.warmed and self.current_learning_iteration == 0:
            obs = self._warm_up(obs)
            self.seconds = time.perf_counter() - began
        self.warmed = True
        if self.evaluator is not None and self.current_learning_iteration == 0 and self.evaluation["last"] is None:
            self._evaluate(0)  # the starting policy (residual: its base expert; warm start: the cloned actor)
            self._checkpoint_after(self.save_checkpoint())
        start = self.current_learning_iteration
        limit = self.settings.time_limit
        for it in range(start, start + num_learning_iterations):
            obs = self._iteration(it, start, start + num_learning_iterations, obs)
            self.current_learning_iteration = it + 1
            self.seconds = time.perf_counter() - began
            if (it + 1) % self.settings.checkpoint_interval == 0 or self._evaluated:
                self._checkpoint_after(self.save_checkpoint())
            if limit is not None and self.seconds >= limit:
                self.save_checkpoint()
                return "time_limit"
        self.save_checkpoint()
        return "done"

    def _iteration(self, it: int, start: int, total: int, obs):
        t0 = time.perf_counter()
        counts = EpisodeCounts()
        keys, protocol = self.pool.keys, self.curriculum.cfg.protocol
        with torch.inference_mode():
            for _ in range(self.cfg["num_steps_per_env"]):
                actions = self.alg.act(obs)
                self._keep_finite_transition(actions)
                obs, rewards, dones, extras = self.env.step(actions)
                self.alg.process_env_step(obs, rewards, dones, extras)
                self.logger.process_env_step(rewards, dones, extras, None)
                counts.add(dones, extras, keys, protocol)
            collect = time.perf_counter() - t0
            self.alg.compute_returns(obs)
        t1 = time.perf_counter()
        fit = self._critic_fit() if it >= self.critic_iterations and self.settings.ppo.critic_fit_epochs else None
        loss = self._critic_update() if it < self.critic_iterations else self._guarded_update()
        if fit is not None:
            loss["critic_fit"] = fit
        if it >= self.critic_iterations and self.demonstrations is not None and self.settings.warm_start.anchor_steps:
            loss["anchor"] = self._anchor()
        learn = time.perf_counter() - t1
        with contextlib.redirect_stdout(io.StringIO()):  # rsl-rl prints a page per iteration; tqdm shows progress
            self.logger.log(it, start, total, collect, learn, loss, self.alg.learning_rate,
                            self.alg.get_policy().output_std, None)  # fmt: skip
        self._after_iteration(it, counts, collect, learn)
        return obs

    def _keep_finite_transition(self, actions: torch.Tensor) -> None:
        """The env gets ``actions`` as they are (a NaN row ends that episode ``unstable``), but the rollout stores
        the policy's mean (zeros where that is not finite either) with its log-probability in such a row: one NaN
        sample would make the whole update NaN."""
        bad = ~torch.isfinite(actions).all(dim=1)
        if bool(bad.any()):
            t = self.alg.transition
            mean = torch.nan_to_num(self.alg.actor.output_mean.detach(), nan=0.0, posinf=0.0, neginf=0.0)
            t.actions = torch.where(bad[:, None], mean, actions)
            t.actions_log_prob = self.alg.actor.get_output_log_prob(t.actions).detach()

    def _guarded_update(self) -> dict:
        """``alg.update()``; if it fails on a non-finite value or leaves a non-finite weight, the weights and the
        optimizer's state from before it are restored and the update is counted in ``bad_updates``."""
        alg = self.alg
        before = copy.deepcopy((alg.actor.state_dict(), alg.critic.state_dict(), alg.optimizer.state_dict()))
        try:
            loss = alg.update()
            params = [*alg.actor.parameters(), *alg.critic.parameters()]
            finite = all(bool(torch.isfinite(p).all()) for p in params)
        except (RuntimeError, ValueError):  # torch.normal with a NaN std, a NaN in a distribution's arguments
            alg.storage.clear()
            loss, finite = {}, False
        if not finite:
            alg.actor.load_state_dict(before[0])
            alg.critic.load_state_dict(before[1])
            alg.optimizer.load_state_dict(before[2])
            self.totals["bad_updates"] += 1
        return loss

    def _critic_update(self) -> dict:
        """Warm-start iterations: fit the critic to this rollout's returns, the actor untouched."""
        from ges_core.training.warm_start import critic_regression

        alg = self.alg
        value = critic_regression(alg.critic, alg.storage, self._critic_adam(), alg.num_learning_epochs,
                                  alg.num_mini_batches, alg.max_grad_norm)  # fmt: skip
        alg.critic.update_normalization(alg.storage.observations.flatten(0, 1))
        alg.storage.clear()
        return {"value": value}

    def _critic_fit(self) -> float:
        """``ppo.critic_fit_epochs`` passes of value regression on this rollout's returns with the critic's own
        optimizer, before the PPO update (which then uses the rollout as collected: its advantages were computed
        with the values of the collection); the mean value loss."""
        from ges_core.training.warm_start import critic_regression

        alg = self.alg
        return critic_regression(alg.critic, alg.storage, self._critic_adam(), self.settings.ppo.critic_fit_epochs,
                                 alg.num_mini_batches, alg.max_grad_norm)  # fmt: skip

    def _critic_adam(self) -> torch.optim.Optimizer:
        """The critic's own Adam, made on first use: the warm start's rate when it runs, else ppo's."""
        if self._critic_optimizer is None:
            rate = (self.settings.warm_start.critic_learning_rate if self.demonstrator is not None
                    else self.settings.ppo.critic_learning_rate)  # fmt: skip
            self._critic_optimizer = torch.optim.Adam(self.alg.critic.parameters(), lr=rate)
        return self._critic_optimizer

    def _anchor(self) -> float:
        """The anchor steps after a PPO update (``warm_start.anchor_steps``); their mean imitation loss."""
        from ges_core.training.warm_start import anchor

        w = self.settings.warm_start
        if self._anchor_optimizer is None:
            self._anchor_optimizer = torch.optim.Adam(self.alg.actor.mlp.parameters(), lr=w.anchor_learning_rate)
            self._anchor_rng = torch.Generator().manual_seed(self.settings.seed + 1)
        return anchor(self.alg.actor, self.demonstrations, self._anchor_optimizer, w.anchor_steps, w.batch_size,
                      self._anchor_rng)  # fmt: skip

    def _warm_up(self, obs):
        """Before the first iteration: the behaviour-cloning warm start when a demonstrator is given, else prime
        the observation normalizers with ``normalizer_warmup`` steps of the initial policy (not learned from;
        the episodes go on from there)."""
        if self.demonstrator is not None:
            return self._warm_start()
        steps = self.settings.ppo.normalizer_warmup
        for _ in range(steps):  # no inference_mode: the statistics it wrote could not be loaded or restored later
            with torch.no_grad():
                self.alg.actor.update_normalization(obs)
                self.alg.critic.update_normalization(obs)
                obs, _, _, _ = self.env.step(self.alg.actor(obs, stochastic_output=True))
            for model in (self.alg.actor, self.alg.critic):
                _floor_std(model)
        self.totals["env_steps"] += steps * self.env.num_envs
        return obs

    def _warm_start(self):
        """Steps 1-3 of :mod:`ges_core.training.warm_start`; writes ``warm_start.json`` in the run folder."""
        from ges_core.training import warm_start as ws

        w, alg = self.settings.warm_start, self.alg
        t0 = time.perf_counter()
        gen = torch.Generator().manual_seed(self.settings.seed)
        if w.all_objects:
            self.pool.set_weights(dict.fromkeys(ws.demo_objects(self.curriculum), 1.0))
        demo = ws.collect_demonstrations(self.env, self.demonstrator, w.samples, w.demo_noise, gen)
        self.pool.set_weights(self.curriculum.weights())
        collect = time.perf_counter() - t0
        ws.fit_normalizer(alg.actor, demo.obs, freeze=w.freeze_actor_normalizer)
        ws.fit_normalizer(alg.critic, demo.obs, freeze=False)
        losses = ws.behaviour_clone(alg.actor, demo, epochs=w.epochs, batch_size=w.batch_size,
                                    learning_rate=w.learning_rate, generator=gen)  # fmt: skip
        self.totals["env_steps"] += demo.env_steps
        record = {
            "demo_env_steps": demo.env_steps, "demo_episodes": demo.episodes, "demo_successes": demo.successes,
            "demo_reasons": demo.reasons, "collect_s": round(collect, 2),
            "clone_s": round(time.perf_counter() - t0 - collect, 2), "imitation_loss": [round(x, 6) for x in losses],
            "objects": ws.demo_objects(self.curriculum) if w.all_objects else self.curriculum.objects(),
        }  # fmt: skip
        self.run_dir.mkdir(parents=True, exist_ok=True)
        (self.run_dir / "warm_start.json").write_text(json.dumps(record, indent=1) + "\n", encoding="utf-8")
        self.warm_start_record = record
        self.demonstrations = demo
        if w.anchor_steps:  # a resumed run reads them back for its anchor steps
            from ges_core.paths import atomic_write_bytes

            buf = io.BytesIO()
            torch.save({"obs": demo.obs, "actions": demo.actions, "env_steps": demo.env_steps}, buf)
            atomic_write_bytes(self.run_dir / DEMOS, buf.getvalue())
        return self.env.get_observations()

    def _after_iteration(self, it: int, counts: EpisodeCounts, collect: float, learn: float) -> None:
        """Totals, curriculum, TensorBoard scalars, one history line, the progress callback."""
        t = self.totals
        t["episodes"], t["paper"], t["peers"] = t["episodes"] + counts.episodes, t["paper"] + counts.paper, \
            t["peers"] + counts.peers  # fmt: skip
        t["nan_actions"] += counts.nan_actions
        t["env_steps"] += self.cfg["num_steps_per_env"] * self.env.num_envs
        self.curriculum.record(counts.outcomes)
        stage = self.curriculum.stage
        interval = self.settings.evaluation.interval
        if self.evaluator is not None and interval and (it + 1) % interval == 0:
            self._evaluate(it + 1)
        promotion = self.curriculum.end_iteration(it + 1)
        if promotion is not None:
            self.pool.set_weights(self.curriculum.weights())
            self._log_promotion(promotion)
        row = {
            "iteration": it + 1, "env_steps": t["env_steps"], "seconds": round(self.seconds + collect + learn, 3),
            "collect_s": round(collect, 4), "learn_s": round(learn, 4), "stage": stage,
            "episodes": counts.episodes, "success_paper": _num(counts.rate("paper")),
            "success_peers": _num(counts.rate("peers")), "window_success": _num(self.curriculum.success_rate()),
            "reasons": counts.reasons, "per_object": counts.per_object, "nan_actions": counts.nan_actions,
            "bad_updates": t["bad_updates"], "update": "critic" if it < self.critic_iterations else "ppo",
            "mean_reward": _num(float(np.mean(self.logger.rewbuffer)) if self.logger.rewbuffer else math.nan),
        }  # fmt: skip
        self._scalars(it, row, counts)
        with open(self.run_dir / "history.jsonl", "a", encoding="utf-8") as fh:
            fh.write(json.dumps(row) + "\n")
        self.last_counts = counts
        if self.on_iteration is not None:
            self.on_iteration(it + 1, row)

    def _checkpoint_after(self, numbered: Path) -> None:
        """After writing checkpoint ``numbered``: copy it to ``best.pt`` when the evaluation just before it was
        the best so far (``evaluation.keep_best``)."""
        if self._new_best and self.settings.evaluation.keep_best:
            from ges_core.paths import atomic_write_bytes

            atomic_write_bytes(numbered.parent / BEST, numbered.read_bytes())
        self._evaluated = self._new_best = False

    def _evaluate(self, done: int) -> None:
        """The in-run evaluation of the weights after ``done`` iterations (a temporary checkpoint file the
        registry's ``ppo`` expert reads; it reads the weights, not the file's ``iter``): one ``evaluations.jsonl``
        line, the curriculum's evaluation rate, the best so far, TensorBoard scalars and the callback's line."""
        path = self.run_dir / "checkpoints" / EVALUATING
        self.save(str(path))
        try:
            result = self.evaluator.evaluate(path, done)
        finally:
            path.unlink(missing_ok=True)
        stage_objects = self.curriculum.objects()
        stage_rate, stage_episodes = result.rate(stage_objects), result.episodes(stage_objects)
        self.curriculum.record_evaluation(stage_rate, stage_episodes)
        rate = result.rate()
        state = self.evaluation
        best = state["best"]
        self._new_best = not math.isnan(rate) and (best is None or _num(rate) > best)  # best is stored rounded
        state["last"] = _num(rate)
        if self._new_best:
            state["best"], state["best_iteration"] = _num(rate), done
        if done == 0:
            state["start"] = result.per_object
        self._evaluated = True
        row = {**result.to_row(), "stage": self.curriculum.stage, "stage_success_paper": _num(stage_rate),
               "best": self._new_best}  # fmt: skip
        if done and state["start"] is not None:
            row["vs_start"] = result.against(state["start"])
        with open(self.run_dir / "evaluations.jsonl", "a", encoding="utf-8") as fh:
            fh.write(json.dumps(row) + "\n")
        w = self.logger.writer
        if w is not None:
            for key in ("success_paper", "success_peers", "stage_success_paper"):
                if row[key] is not None:
                    w.add_scalar(f"Evaluation/{key}", row[key], done)
        if self.on_evaluation is not None:
            self.on_evaluation(describe_evaluation(row, len(result.per_object), self.evaluator.config.envs))

    def _scalars(self, it: int, row: dict, counts: EpisodeCounts) -> None:
        w = self.logger.writer
        if w is None:
            return
        for key in ("success_paper", "success_peers"):
            if row[key] is not None:
                w.add_scalar(f"Success/{key.split('_')[1]}_episodes", row[key], it)
        w.add_scalar("Episodes/ended", counts.episodes, it)
        for name, n in counts.reasons.items():
            w.add_scalar(f"Episodes/{name}", n, it)
        w.add_scalar("Faults/nan_actions", counts.nan_actions, it)
        w.add_scalar("Faults/nan_actions_total", self.totals["nan_actions"], it)
        w.add_scalar("Faults/bad_updates_total", self.totals["bad_updates"], it)
        w.add_scalar("Curriculum/stage", self.curriculum.stage, it)
        w.add_scalar("Curriculum/objects", len(self.curriculum.objects()), it)
        if row["window_success"] is not None:
            w.add_scalar("Curriculum/window_success", row["window_success"], it)

    def _log_promotion(self, promotion) -> None:
        line = promotion.describe()
        with open(self.run_dir / "curriculum.log", "a", encoding="utf-8") as fh:
            fh.write(line + "\n")
        if self.logger.writer is not None:
            self.logger.writer.add_text("Curriculum/promotion", line, promotion.iteration)
        if self.on_promotion is not None:
            self.on_promotion(line)

    # -- checkpoints ------------------------------------------------------------------------------
    def checkpoint_dict(self) -> dict:
        """rsl-rl's saved dict plus the ``ges`` section (see :mod:`ges_core.training.checkpoint`)."""
        data = self.alg.save()
        data["iter"], data["infos"] = self.current_learning_iteration, None
        env = self.env.env
        state = {
            "curriculum": self.curriculum.state_dict(),
            "totals": dict(self.totals),
            "seconds": self.seconds,
            "torch_rng": torch.get_rng_state(),
            "env_rng": env.random.state(),
            "logger": {"tot_timesteps": self.logger.tot_timesteps, "tot_time": self.logger.tot_time},
            "evaluation": dict(self.evaluation),
        }
        data["ges"] = {"format": FORMAT, "version": VERSION, **self.meta, "state": state}
        return data

    def save_checkpoint(self) -> Path:
        """Write the checkpoint of the iterations done (atomically) into ``run_dir/checkpoints``."""
        folder = self.run_dir / "checkpoints"
        return write_checkpoint(folder, self.checkpoint_dict(), self.current_learning_iteration,
                                self.settings.keep_checkpoints)  # fmt: skip

    def save(self, path: str, infos: dict | None = None) -> None:
        """rsl-rl's ``save`` (a single file), atomic and with the ``ges`` section."""
        from ges_core.paths import atomic_write_bytes

        buf = io.BytesIO()
        torch.save(self.checkpoint_dict(), buf)
        atomic_write_bytes(Path(path), buf.getvalue())

    def resume_from(self, data: dict) -> None:
        """Continue from a checkpoint dict: weights, optimizer, iterations, curriculum, random states, totals; the
        run folder's logs are cut back to its iterations (:func:`trim_run_logs`)."""
        self.alg.load(data, None, strict=True)
        self.current_learning_iteration = int(data["iter"])
        trim_run_logs(self.run_dir, self.current_learning_iteration)
        state = data["ges"]["state"]
        self.curriculum.load_state_dict(state["curriculum"])
        self.pool.set_weights(self.curriculum.weights())
        self.totals.update(state["totals"])
        self.seconds = float(state["seconds"])
        torch.set_rng_state(state["torch_rng"])
        self.env.env.random.set_state(state["env_rng"])
        self.logger.tot_timesteps = state["logger"]["tot_timesteps"]
        self.logger.tot_time = state["logger"]["tot_time"]
        self.evaluation.update(state.get("evaluation") or {})  # absent before in-run evaluations
        self.warmed = True
        if self.demonstrator is not None and self.settings.warm_start.freeze_actor_normalizer:
            from ges_core.training.warm_start import freeze_normalizer

            freeze_normalizer(self.alg.actor)  # ``until`` is not in the state dict
        if self.demonstrator is not None and self.settings.warm_start.anchor_steps:
            self.demonstrations = _read_demonstrations(self.run_dir / DEMOS)


def trim_run_logs(run_dir: Path, done: int) -> None:
    """Drop what a killed run logged after its checkpoint of ``done`` iterations: the lines of ``history.jsonl``,
    ``evaluations.jsonl`` and ``curriculum.log`` of later iterations, and a line cut short (rewritten atomically).
    The resumed run repeats those iterations and logs them again, so each iteration keeps one line."""
    from ges_core.paths import atomic_write_text

    def iteration(name: str, line: str) -> float:
        try:
            if name == "curriculum.log":  # "iteration N: curriculum stage ..."
                return int(line.split(":", 1)[0].split()[-1])
            return int(json.loads(line)["iteration"])
        except (ValueError, KeyError, IndexError, TypeError):
            return math.inf  # a line the kill cut short: dropped

    for name in ("history.jsonl", "evaluations.jsonl", "curriculum.log"):
        path = run_dir / name
        if not path.is_file():
            continue
        lines = [line for line in path.read_text(encoding="utf-8").splitlines() if line.strip()]
        kept = [line for line in lines if iteration(name, line) <= done]
        if len(kept) < len(lines):
            atomic_write_text(path, "".join(line + "\n" for line in kept))


BEST = "best.pt"
"""The checkpoint of the best in-run evaluation so far, beside ``last.pt`` (``evaluation.keep_best``)."""
EVALUATING = "evaluating.pt"
"""The temporary checkpoint an in-run evaluation reads (removed after it)."""


DEMOS = "demonstrations.pt"
"""The warm start's demonstrations in the run folder (written when ``anchor_steps`` > 0; read on resume)."""


def _read_demonstrations(path: Path):
    """The Demonstrations saved at ``path``; AssetError saying how to go on when the file is missing."""
    from ges_core.errors import AssetError
    from ges_core.training.warm_start import Demonstrations

    if not path.is_file():
        raise AssetError(
            f"{path} is missing: the run's anchor steps (warm_start.anchor_steps) need the warm start's "
            "demonstrations; resume with -o warm_start.anchor_steps=0, or start a new run"
        )
    data = torch.load(path, weights_only=True)
    return Demonstrations(data["obs"], data["actions"], int(data["env_steps"]))


STD_FLOOR = 0.1
"""Smallest standard deviation the normalizer keeps after the warm-up, in each feature's unit. A feature constant
during the warm-up (contact flags and tip forces before any touch) has std 0 and would be divided by rsl-rl's eps
(0.01) once it moves: inputs of 100 and more, policy means of 20-40 after a 2-env warm-up (test_train_expert)."""


def _floor_std(model) -> None:
    """Raise the running std (and variance) of ``model``'s observation normalizer to at least :data:`STD_FLOOR`."""
    norm = getattr(model, "obs_normalizer", None)
    if norm is None or not hasattr(norm, "_var"):
        return
    norm._var.clamp_(min=STD_FLOOR**2)
    norm._std.copy_(norm._var.sqrt())


def _num(value: float) -> float | None:
    """JSON-safe: None for NaN."""
    return None if value is None or (isinstance(value, float) and math.isnan(value)) else round(float(value), 4)
