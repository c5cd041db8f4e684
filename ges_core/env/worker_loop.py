"""The child side of :class:`~ges_core.env.workers.SubprocVecEnv`: one worker process stepping its slice of envs.

A worker builds its own :class:`~ges_core.env.grasp_env.GraspEnv` (its own backend) over the global env ids it
was given, wraps it in a :class:`WorkerVecEnv` (a :class:`~ges_core.env.vec_env.GraspVecEnv`, so NaN actions,
auto-resets, episode bookkeeping and every per-env extra are computed by the one implementation) and then
answers commands from its pipe. Each step reads its actions from, and writes its per-env results into, its
columns of the shared tensors the main process allocated (:data:`~ges_core.env.workers.BUFFERS`); only a small
dict goes back through the pipe. It exits on ``close``, when the pipe's other end closes, and (Linux) when the
parent process dies (``PR_SET_PDEATHSIG``), so no worker outlives a killed trainer.
"""

from __future__ import annotations

import contextlib
import os
import pickle
import sys
import traceback
from collections.abc import Callable

import numpy as np
import torch

from ges_core.env.grasp_env import GraspEnv
from ges_core.env.reward import TERMS
from ges_core.env.vec_env import GraspVecEnv
from ges_core.errors import GesError
from ges_core.process_guard import die_with_parent

__all__ = ["KNOWN_EXTRAS", "WorkerVecEnv", "worker_main"]

KNOWN_EXTRAS = ("time_outs", "log", "end_reason", "peer_success", "max_rise", "entry", "episode_metrics")
"""Extras the shared buffers carry (``log`` is rebuilt in the main process from per-env values); any other key
a GraspVecEnv adds travels pickled through the pipe, one per-env tensor per worker, concatenated in env order."""


class WorkerVecEnv(GraspVecEnv):
    """A GraspVecEnv that also keeps, per step, what the main process needs to rebuild the whole batch's log:
    the raw reward terms (T, n), the unstable flags (n,) and every env's Table 3 metrics read before the resets."""

    def _extras(self, code: np.ndarray, done, terms: dict, unstable) -> dict:
        self.raw_terms = self.env.terms_array(terms)
        self.raw_unstable = unstable
        self.raw_metrics = self.metrics.read(torch.arange(self.num_envs))
        return super()._extras(code, done, terms, unstable)

    def describe(self) -> dict:
        """What the main process needs before allocating the buffers: sizes, layouts, names, config.

        The layouts travel as plain pickle bytes: the pipe's pickler would move their tensors' storage into shared
        memory *in place* here, leaving the numpy views the layouts cache (``ActionLayout._lower_np``) pointing
        at freed memory (seen: garbage joint targets in every worker)."""
        env = self.env
        names = list(self.metrics.read(torch.arange(0)))
        return {
            "num_envs": self.num_envs, "num_actions": self.num_actions, "obs_size": env.obs_layout.size,
            "layouts": pickle.dumps((env.obs_layout, env.act_layout)), "cfg": env.cfg, "terms": tuple(TERMS),
            "metrics": names, "pool_keys": None if env.pool is None else env.pool.keys,
        }  # fmt: skip

    def attach(self, bufs: dict[str, torch.Tensor]) -> None:
        """Use this worker's slices of the shared buffers; the episode counter becomes the shared one."""
        self.bufs = {name: t.numpy() for name, t in bufs.items()}
        bufs["episode_length"].copy_(self.episode_length_buf)
        self.episode_length_buf = bufs["episode_length"]
        self.bufs["obs"][:] = self._obs.numpy()

    def step_into_buffers(self) -> dict:
        """One step with the actions in the shared buffer; results into the shared buffers. Returns the
        extras the buffers do not carry (usually none)."""
        b = self.bufs
        obs, reward, done, extras = self.step(torch.from_numpy(b["actions"]))
        b["obs"][:] = obs["policy"].numpy()
        b["reward"][:] = reward.numpy()
        b["done"][:] = done.numpy() != 0
        for name in ("time_outs", "end_reason", "peer_success", "max_rise", "entry"):
            b[name][:] = extras[name].numpy()
        b["terms"][:] = self.raw_terms
        b["unstable"][:] = False if self.raw_unstable is None else self.raw_unstable
        b["bad"][:] = False if self.env.bad_actions is None else self.env.bad_actions
        for i, name in enumerate(n for n in self.raw_metrics if n != "steps"):
            b["metrics"][i] = self.raw_metrics[name].numpy()
        b["metric_steps"][:] = self.raw_metrics["steps"].numpy()
        return {k: _by_value(v) for k, v in extras.items() if k not in KNOWN_EXTRAS}


def _by_value(value):
    """A tensor as a numpy array (numpy pickles by value; a tensor through the pipe would be moved to shared memory
    in place, under any view of its old memory)."""
    return value.numpy(force=True) if isinstance(value, torch.Tensor) else value


def worker_main(conn, make_env: Callable[[tuple[int, ...]], GraspEnv], env_ids: tuple[int, ...], seed: int,
                parent_pid: int) -> None:  # fmt: skip
    """Entry point of a worker process: build, report, then serve commands until ``close`` or the parent goes.

    Ends with ``os._exit``: a normal interpreter shutdown after SAPIEN hung in native code (no Python frame) for
    over 5 s in every worker (measured 2026-12-02), and a worker has nothing left to flush but its std streams."""
    die_with_parent(parent_pid)
    torch.set_num_threads(1)
    venv, code = None, 0
    try:
        venv = WorkerVecEnv(make_env(tuple(env_ids)), seed=seed)
        conn.send(("ready", venv.describe()))
        _serve(conn, venv)
    except (EOFError, BrokenPipeError, KeyboardInterrupt):
        pass  # the main process went away (or was interrupted): nothing to answer
    except BaseException as exc:  # reported to the main process, which raises it there
        _report(conn, exc)
        code = 1
    finally:
        if venv is not None:
            venv.close()
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)


def _serve(conn, venv: WorkerVecEnv) -> None:
    """Answer commands: ('buffers', dict), ('step', weights | None), ('rng_state', None), ('set_rng_state',
    states), ('reseed', seed), ('attr', name), ('close', None)."""
    while True:
        cmd, arg = conn.recv()
        if cmd == "close":
            conn.send(("ok", None))
            return
        if cmd == "buffers":
            venv.attach(arg)
            out = None
        elif cmd == "step":
            if arg is not None:
                venv.env.pool.set_weights(arg)
            out = venv.step_into_buffers()
        elif cmd == "rng_state":
            out = venv.env.random.state()
        elif cmd == "set_rng_state":
            out = venv.env.random.set_state(arg)
        elif cmd == "reseed":
            out = venv.env.reseed(arg)
        elif cmd == "attr":
            out = _attribute(venv.env, arg)
        else:
            raise ValueError(f"env worker: unknown command {cmd!r}")
        conn.send(("ok", out))


def _attribute(env: GraspEnv, name: str) -> tuple[str, object]:
    """('value', the env's attribute ``name`` with tensors as numpy arrays) or ('missing', why)."""
    try:
        value = getattr(env, name)
    except AttributeError as exc:
        return "missing", str(exc)
    if isinstance(value, dict):
        return "value", {k: _by_value(v) for k, v in value.items()}
    return "value", _by_value(value)


def _report(conn, exc: BaseException) -> None:
    """Send ('error', the exception if it is one of ours and pickles, else None, its traceback text)."""
    text = traceback.format_exc()
    payload = exc if isinstance(exc, GesError) else None
    try:
        conn.send(("error", payload, text))
    except Exception:  # unpicklable exception or a closed pipe: the text alone, or nothing
        with contextlib.suppress(Exception):
            conn.send(("error", None, text))
