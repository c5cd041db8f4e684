"""Env workers: a vectorized grasp environment whose envs are split across worker processes (both CPU cores).

:class:`SubprocVecEnv` is an rsl-rl ``VecEnv`` with :class:`~ges_core.env.vec_env.GraspVecEnv`'s interface and
extras. Its ``num_envs`` envs are split into ``workers`` contiguous slices; each slice lives in its own spawned
process (:mod:`ges_core.env.worker_loop`) with its own simulator backend and :class:`GraspEnv`, torch and OpenMP
at one thread. The main process runs PPO. Per step the actions go to the workers and the per-env results come
back through shared tensors (torch shared memory); the pipe carries only a command and a small reply, so
nothing the size of an observation is pickled. The step's ``extras["log"]`` is rebuilt here from per-env
values exactly as one GraspVecEnv computes it over the whole batch.

Deterministic: every env's random streams are seeded by its *global* index (:mod:`ges_core.env.randomization`),
and each env is its own simulator scene, so for a seed ``workers=2`` gives the same per-env trajectories,
rewards and extras as ``workers=1`` (tests/test_env_workers.py compares them bit for bit).

The curriculum's pool weights (``venv.env.pool.set_weights``) reach the workers with the next step; the random
states (``venv.env.random.state()`` / ``set_state``) are gathered from and scattered to the workers in env
order, the same list one in-process env gives, so checkpoints move between worker counts.

Faults: a worker that dies (killed, crashed, an exception) or gives no answer within ``timeout`` seconds raises
SimulationError in the main process naming the worker, its pid and its env ids (an exception raised in the worker
comes with its traceback; an error of ours raised while building, e.g. a ConfigError, is raised as it is); the
other workers are stopped and every later call raises "closed". Workers exit with their parent (Linux
``PR_SET_PDEATHSIG``, else at the pipe's end-of-file); :meth:`SubprocVecEnv.close` joins them.
"""

from __future__ import annotations

import contextlib
import multiprocessing as mp
import os
import pickle
import signal
import time
from collections.abc import Callable, Iterator
from multiprocessing.connection import wait

import numpy as np
import torch
from rsl_rl.env import VecEnv
from tensordict import TensorDict

from ges_core.arrays import checked_array
from ges_core.env.grasp_env import GraspEnv
from ges_core.env.metrics import METRIC_NAMES
from ges_core.env.success import EndReason
from ges_core.env.vec_env import _stable_means
from ges_core.env.worker_loop import worker_main
from ges_core.errors import ConfigError, GesError, SimulationError

__all__ = ["BUFFERS", "EnvView", "SubprocVecEnv", "split_envs"]

BUFFERS = (
    "actions", "obs", "reward", "done", "time_outs", "end_reason", "peer_success", "max_rise", "entry",
    "unstable", "bad", "terms", "metrics", "metric_steps", "episode_length",
)  # fmt: skip
"""Shared tensors, each over the whole batch; a worker reads and writes its envs' columns only."""

_THREAD_VARS = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")
_STOP_WAIT = 5.0
"""Seconds close() waits for a worker to exit after 'close' before killing it."""


def split_envs(num_envs: int, workers: int) -> list[tuple[int, ...]]:
    """The global env ids of each worker: ``workers`` contiguous slices, sizes differing by at most one."""
    if not 1 <= workers <= num_envs:
        raise ConfigError(f"env workers: {workers} worker(s) for {num_envs} env(s); give 1 <= workers <= num_envs")
    return [tuple(int(e) for e in part) for part in np.array_split(np.arange(num_envs), workers)]


class SubprocVecEnv(VecEnv):
    """``num_envs`` grasp envs split across ``workers`` processes, stepped together (module docs).

    make_env: a picklable callable (a module-level function or a ``functools.partial`` of one) taking the
    global env ids of one worker and returning its GraspEnv over ``len(ids)`` envs, built with
    ``env_index=ids`` (its random streams); called in the worker. hand and pool: the main process's hand model
    and GraspPool (the same the workers use: layouts, the curriculum's weights). timeout: seconds to wait for any
    one answer of a live worker before it counts as hung; build_timeout: the same for starting and building (a
    process start imports torch and the simulator: seconds when idle, a minute and more on a loaded machine).
    """

    def __init__(self, make_env: Callable[[tuple[int, ...]], GraspEnv], num_envs: int, workers: int, *, hand,
                 pool=None, seed: int = 0, timeout: float = 120.0, build_timeout: float = 900.0) -> None:  # fmt: skip
        self.slices = split_envs(num_envs, workers)
        self.num_envs, self.device, self.timeout = num_envs, "cpu", float(timeout)
        self.fault_counts = {"nan_actions": 0}
        """Running totals since construction: ``nan_actions``, env steps whose action row held NaN or inf."""
        self._procs: list = []
        self._conns: list = []
        self._closed = False
        torch.manual_seed(seed)  # as GraspVecEnv does: the main process's torch stream is the same with workers
        try:
            self._start(make_env, seed)
            info = self._gather("ready", "build its environment", build_timeout)
            self._setup(info, hand, pool)
        except BaseException:
            self._stop()
            raise

    # -- start-up ----------------------------------------------------------------------------------
    def _start(self, make_env, seed: int) -> None:
        ctx = mp.get_context("spawn")  # not fork: the parent holds torch threads a fork would copy half-locked
        with _one_thread_env():
            for ids in self.slices:
                parent, child = ctx.Pipe()
                proc = ctx.Process(target=worker_main, args=(child, make_env, ids, seed, os.getpid()), daemon=True,
                                   name=f"ges-env-worker-{len(self._procs)}")  # fmt: skip
                try:
                    proc.start()
                except (pickle.PicklingError, AttributeError, TypeError) as exc:  # spawn pickles the arguments
                    parent.close()
                    child.close()
                    raise ConfigError(
                        f"env workers: make_env must be picklable (a module-level function or a functools.partial of "
                        f"one), got {make_env!r}: {exc}"
                    ) from exc
                child.close()  # the worker holds the only other end: its death is our end-of-file
                self._procs.append(proc)
                self._conns.append(parent)

    def _setup(self, info: list[dict], hand, pool) -> None:
        first = info[0]
        for w, other in enumerate(info[1:], start=1):
            if (other["obs_size"], other["num_actions"], other["pool_keys"]) != (
                first["obs_size"], first["num_actions"], first["pool_keys"]
            ):  # fmt: skip
                raise ConfigError(f"env worker {w} built another environment than worker 0 (sizes or pool differ)")
        if pool is not None and first["pool_keys"] != pool.keys:
            raise ConfigError("env workers: the workers' pool holds other entries than the main process's pool")
        self.num_actions, self.cfg = first["num_actions"], first["cfg"]
        self.max_episode_length = self.cfg.episode_length
        obs_layout, act_layout = pickle.loads(first["layouts"])
        self.env = EnvView(self, hand, pool, obs_layout, act_layout, self.cfg)
        self._terms, self._metric_names = first["terms"], [m for m in first["metrics"] if m != "steps"]
        self._action_doc = act_layout.describe()
        self._alloc(first["obs_size"])
        self._call("buffers", [self._worker_buffers(ids) for ids in self.slices], "attach its buffers")
        self._obs = torch.from_numpy(self._np["obs"].copy())
        self._sent_weights = None if pool is None else pool.weights

    def _alloc(self, obs_size: int) -> None:
        n, f64, b = self.num_envs, torch.float64, torch.bool
        shapes = {
            "actions": ((n, self.num_actions), f64), "obs": ((n, obs_size), torch.float32),
            "reward": ((n,), torch.float32), "done": ((n,), b), "time_outs": ((n,), b),
            "end_reason": ((n,), torch.int64), "peer_success": ((n,), b), "max_rise": ((n,), f64),
            "entry": ((n,), torch.int64), "unstable": ((n,), b), "bad": ((n,), b),
            "terms": ((len(self._terms), n), f64), "metrics": ((len(self._metric_names), n), f64),
            "metric_steps": ((n,), torch.int64), "episode_length": ((n,), torch.int64),
        }  # fmt: skip
        self._bufs = {name: torch.zeros(shapes[name][0], dtype=shapes[name][1]).share_memory_() for name in BUFFERS}
        self._np = {name: t.numpy() for name, t in self._bufs.items()}

    def _worker_buffers(self, ids: tuple[int, ...]) -> dict[str, torch.Tensor]:
        lo, hi = ids[0], ids[-1] + 1
        return {k: (t[:, lo:hi] if k in ("terms", "metrics") else t[lo:hi]) for k, t in self._bufs.items()}

    # -- the VecEnv interface ----------------------------------------------------------------------
    @property
    def episode_length_buf(self) -> torch.Tensor:
        """(n,) int64 control steps of each env's running episode (shared with the workers)."""
        return self._bufs["episode_length"]

    @episode_length_buf.setter
    def episode_length_buf(self, value: torch.Tensor) -> None:
        self._bufs["episode_length"].copy_(value)  # rsl-rl may assign a new tensor: the workers read this one

    def get_observations(self) -> TensorDict:
        """Observations of the current step: {"policy": (num_envs, obs size) float32}."""
        self._check_open("get_observations")
        return TensorDict({"policy": self._obs}, batch_size=[self.num_envs])

    def step(self, actions: torch.Tensor) -> tuple[TensorDict, torch.Tensor, torch.Tensor, dict]:
        """As :meth:`GraspVecEnv.step`: actions (num_envs, num_actions) in [-1, 1]; rewards (n,) float32, dones
        (n,) int64, extras (``time_outs``, ``log``, ``end_reason``, ``peer_success``, ``max_rise``, ``entry``,
        ``episode_metrics`` when an episode ended). A NaN or inf row ends that env ``unstable``."""
        self._check_open("step")
        a = checked_array(actions, (self.num_envs, self.num_actions), "GraspVecEnv.step: actions",
                          layout=self._action_doc, finite=False)  # fmt: skip
        self._np["actions"][:] = a
        replies = self._call("step", [self._weights_update()] * len(self._procs), "step")
        b = self._np
        nan_actions = int(b["bad"].sum())
        self.fault_counts["nan_actions"] += nan_actions
        done = b["done"].copy()
        extras = self._extras(b["end_reason"].copy(), done, nan_actions, replies)
        self._obs = torch.from_numpy(b["obs"].copy())
        reward = torch.from_numpy(b["reward"].copy())
        return self.get_observations(), reward, torch.from_numpy(done.astype(np.int64)), extras

    def close(self) -> None:
        """Stop the workers (each closes its backend) and join them; later calls raise SimulationError. Twice is
        harmless."""
        if not self._closed:
            self._closed = True
            self._stop()

    @property
    def closed(self) -> bool:
        return self._closed

    @property
    def pids(self) -> list[int]:
        """Process ids of the workers, worker order (for CPU accounting; the processes end with :meth:`close`)."""
        return [p.pid for p in self._procs]

    # -- extras ------------------------------------------------------------------------------------
    def _extras(self, code: np.ndarray, done: np.ndarray, nan_actions: int, replies: list[dict]) -> dict:
        """GraspVecEnv.step's extras for the whole batch, from the per-env values the workers wrote."""
        b = self._np
        unstable = b["unstable"]
        means = _stable_means(b["terms"], unstable.copy() if unstable.any() else None)
        log = dict(zip([f"/reward/{name}" for name in self._terms], torch.from_numpy(means).unbind(), strict=True))
        reason, any_done = torch.from_numpy(code), bool(done.any())
        metrics = self._episode_metrics() if any_done else None
        if any_done:
            log.update(self._episode_log(reason, torch.from_numpy(done), metrics))
        log["/faults/nan_actions"] = torch.tensor(float(nan_actions))
        extras = {"time_outs": torch.from_numpy(b["time_outs"].copy()), "log": log, "end_reason": reason}
        for name in ("peer_success", "max_rise", "entry"):
            extras[name] = torch.from_numpy(b[name].copy())
        if metrics is not None:
            extras["episode_metrics"] = metrics
        for key, value in replies[0].items():  # extras a GraspVecEnv adds beyond KNOWN_EXTRAS: per-env arrays
            extras[key] = torch.from_numpy(np.concatenate([r[key] for r in replies])) if isinstance(
                value, np.ndarray) else value  # fmt: skip
        return extras

    def _episode_metrics(self) -> dict[str, torch.Tensor]:
        """Every env's Table 3 metrics so far, read before the resets: name -> (n,) float64, plus ``steps``."""
        out = {name: torch.from_numpy(self._np["metrics"][i].copy()) for i, name in enumerate(self._metric_names)}
        out["steps"] = torch.from_numpy(self._np["metric_steps"].copy())
        return out

    def _episode_log(self, reason: torch.Tensor, done: torch.Tensor, metrics: dict) -> dict[str, torch.Tensor]:
        """Rates of each end reason and both protocols and the mean Table 3 metrics over the episodes that ended:
        the same operations as GraspVecEnv._episode_log (the determinism test compares both logs)."""
        ended = reason[done]
        log = {f"/end/{r.name.lower()}": (ended == r).float().mean() for r in EndReason if r is not EndReason.RUNNING}
        log["/success/paper"] = (ended == EndReason.SUCCESS).float().mean()
        log["/success/peers"] = torch.from_numpy(self._np["peer_success"])[done].float().mean()
        ids = done.nonzero().flatten()
        log.update({f"/metrics/{name}": metrics[name][ids].mean() for name in METRIC_NAMES})
        return log

    def _weights_update(self) -> np.ndarray | None:
        """The pool's weights if they changed since last sent (GraspPool.set_weights makes a new array), else None."""
        pool = self.env.pool
        if pool is None or pool.weights is self._sent_weights:
            return None
        self._sent_weights = pool.weights
        return pool.weights

    # -- talking to the workers --------------------------------------------------------------------
    def _call(self, cmd: str, args: list, doing: str) -> list:
        """Send ``(cmd, args[w])`` to every worker, return their answers in worker order."""
        for w, conn in enumerate(self._conns):
            try:
                conn.send((cmd, args[w]))
            except (BrokenPipeError, ConnectionResetError, EOFError):
                self._fail(w, doing, "its pipe is closed")
        return self._gather("ok", doing)

    def _gather(self, expect: str, doing: str, timeout: float | None = None) -> list:
        """One answer per worker (tag ``expect``); SimulationError when one dies, fails or stays silent for
        ``timeout`` s (None: :attr:`timeout`)."""
        answers: dict[int, object] = {}
        timeout = self.timeout if timeout is None else float(timeout)
        deadline = time.monotonic() + timeout
        waiting = dict(enumerate(self._conns))
        while waiting:
            ready = wait([*waiting.values(), *(self._procs[w].sentinel for w in waiting)],
                         timeout=max(0.0, deadline - time.monotonic()))  # fmt: skip
            if not ready:
                w = min(waiting)
                self._fail(w, doing, f"gave no answer in {timeout:g} s (hung? raise the timeout if it is "
                                     "legitimately that slow)")  # fmt: skip
            for w in [w for w, c in waiting.items() if c in ready or self._procs[w].sentinel in ready]:
                answers[w] = self._receive(w, expect, doing)
                del waiting[w]
        return [answers[w] for w in range(len(self._conns))]

    def _receive(self, w: int, expect: str, doing: str):
        conn = self._conns[w]
        try:
            if not conn.poll():
                raise EOFError
            tag, *payload = conn.recv()
        except (EOFError, ConnectionResetError, OSError):
            self._procs[w].join(1.0)
            self._fail(w, doing, _exit_text(self._procs[w].exitcode))
        if tag == "error":
            exc, text = payload
            if isinstance(exc, GesError) and expect == "ready":
                self._stop()
                raise exc
            self._fail(w, doing, f"raised an exception:\n{text.rstrip()}")
        return payload[0]

    def _fail(self, w: int, doing: str, what: str):
        """Stop every worker and raise SimulationError naming worker ``w``, its pid and its env ids."""
        proc, ids = self._procs[w], self.slices[w]
        self._closed = True
        self._stop(wait=1.0)
        raise SimulationError(
            f"env worker {w} (pid {proc.pid}, envs {ids[0]}-{ids[-1]} of {self.num_envs}) {what} while asked to "
            f"{doing}; every worker is stopped and this environment is closed: build a new one (a simulator "
            "blow-up inside a worker ends that env's episode 'unstable' and never gets here)",
            env_ids=list(ids),
        )

    def _stop(self, wait: float = _STOP_WAIT) -> None:
        """Ask every live worker to close, wait up to ``wait`` s, kill what is left, close the pipes."""
        for proc, conn in zip(self._procs, self._conns, strict=True):
            if proc.is_alive():
                with contextlib.suppress(OSError, ValueError):
                    conn.send(("close", None))
        deadline = time.monotonic() + wait
        for proc in self._procs:
            proc.join(max(0.0, deadline - time.monotonic()))
            if proc.is_alive():
                proc.kill()
                proc.join(_STOP_WAIT)
        for conn in self._conns:
            conn.close()
        self._conns = [_ClosedConn() for _ in self._procs]

    def _check_open(self, method: str) -> None:
        if self._closed:
            raise SimulationError(
                f"SubprocVecEnv.{method}: the environment is closed (closed, or a worker failed); build a new one"
            )

    # -- what EnvView forwards -----------------------------------------------------------------------
    def rng_state(self) -> list:
        """Every env's random-stream states, in env order (the list one in-process env gives)."""
        self._check_open("env.random.state")
        return [s for part in self._call("rng_state", [None] * len(self._procs), "send its random states")
                for s in part]  # fmt: skip

    def set_rng_state(self, state: list) -> None:
        """Restore :meth:`rng_state` (a list of one entry per env, in env order)."""
        self._check_open("env.random.set_state")
        if len(state) == 4 and all(isinstance(s, dict) for s in state):  # saved before per-env streams
            self._call("set_rng_state", [state] * len(self._procs), "restore random states")
            return
        if len(state) != self.num_envs:
            raise ConfigError(
                f"randomization state: {len(state)} entries, this environment has {self.num_envs} envs; resume with "
                "the num_envs the state was saved with"
            )
        self._call("set_rng_state", [state[ids[0] : ids[-1] + 1] for ids in self.slices], "restore random states")

    def env_attribute(self, name: str):
        """A GraspEnv attribute read in every worker and joined in env order: arrays and tensors (first axis: envs)
        concatenated, lists joined, dicts of those key by key, anything else as worker 0 has it; tensors come
        back as numpy arrays. A copy: writing to it changes nothing in the workers. AttributeError if the GraspEnv
        has none."""
        self._check_open(f"env.{name}")
        answers = self._call("attr", [name] * len(self._procs), f"read env.{name}")
        if answers[0][0] == "missing":
            raise AttributeError(f"{answers[0][1]} (read through SubprocVecEnv.env, the env workers' GraspEnv)")
        return _join([value for _, value in answers])

    def reseed(self, seed: int) -> None:
        """Restart every env's random streams from ``seed`` (GraspEnv.reseed in each worker)."""
        self._check_open("env.reseed")
        self._call("reseed", [seed] * len(self._procs), "reseed")


class _ClosedConn:
    """Stands in for a closed pipe: sending fails like a broken one."""

    def send(self, _obj) -> None:
        raise BrokenPipeError

    def close(self) -> None:
        pass


class _RandomView:
    """``env.random`` of a SubprocVecEnv: the random states live in the workers."""

    def __init__(self, venv: SubprocVecEnv) -> None:
        self.state, self.set_state = venv.rng_state, venv.set_rng_state


class EnvView:
    """``venv.env`` of a :class:`SubprocVecEnv`: what the runner, the residual wrapper and ExpertContext.of_env read
    of a GraspEnv (``n``, ``hand``, ``cfg``, layouts, ``pool``, ``random``), without a simulator here."""

    def __init__(self, venv: SubprocVecEnv, hand, pool, obs_layout, act_layout, cfg) -> None:
        self.n, self.hand, self.pool, self.cfg = venv.num_envs, hand, pool, cfg
        self.obs_layout, self.act_layout = obs_layout, act_layout
        self.random = _RandomView(venv)
        self.reseed = venv.reseed
        self._venv = venv

    @property
    def closed(self) -> bool:
        return self._venv.closed

    def close(self) -> None:
        self._venv.close()

    def __getattr__(self, name: str):
        """Any other GraspEnv attribute (``wrist_target``, ``entry``, ``object_ids``, ...), read from the workers
        and joined in env order (:meth:`SubprocVecEnv.env_attribute`): a copy, one round trip per read."""
        if name.startswith("_"):
            raise AttributeError(name)
        return self._venv.env_attribute(name)

    def check_open(self, who: str) -> None:
        """SimulationError naming ``who`` once the environment is closed."""
        if self.closed:
            raise SimulationError(f"{who}: the environment is closed; build a new one")


def _join(parts: list):
    """Per-worker values of one attribute joined in env order (see :meth:`SubprocVecEnv.env_attribute`)."""
    first = parts[0]
    if isinstance(first, np.ndarray) and first.ndim:
        return np.concatenate(parts)
    if isinstance(first, list):
        return [v for part in parts for v in part]
    if isinstance(first, dict):
        return {k: _join([p[k] for p in parts]) for k in first}
    return first


@contextlib.contextmanager
def _one_thread_env() -> Iterator[None]:
    """OpenMP, MKL and OpenBLAS at one thread in the processes started inside (restored afterwards)."""
    saved = {k: os.environ.get(k) for k in _THREAD_VARS}
    os.environ.update(dict.fromkeys(_THREAD_VARS, "1"))
    try:
        yield
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def _exit_text(code: int | None) -> str:
    """'died (killed by SIGKILL)' / 'died (exit code 1)' / 'closed its pipe'."""
    if code is None:
        return "closed its pipe"
    if code < 0:
        with contextlib.suppress(ValueError):
            return f"died (killed by {signal.Signals(-code).name})"
    return f"died (exit code {code})"
