"""Ray for `bags` and the tiled `estimate`: a local Ray started inside this process, or a running cluster joined by
address, and workers that each build the estimator once and then take bags or tiles.

Ray schedules the workers (actors), restarts one whose process dies and retries the task it was running; a retried
bag continues its own OUT.partial (`bag`'s resume), so nothing is lost or written twice. Imported only by commands
given --workers or --address: Ray starts in a second or two, which `estimate` without them never pays.
"""

from __future__ import annotations

import argparse
import os
import re
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import TripletNormalError

#: How often Ray restarts a worker whose process died, and retries the task it was running.
RETRIES = 3
#: Seconds `--address` may take to answer before the command gives up with one line.
CONNECT_TIMEOUT_S = 20


class ClusterError(TripletNormalError):
    """Ray could not be started or reached."""


def default_workers(device: str) -> int:
    """One worker per GPU when the estimator runs on CUDA and torch sees GPUs, else one per two cores."""
    import torch

    if device != "cpu" and torch.cuda.is_available():
        return torch.cuda.device_count()
    return max(1, (os.cpu_count() or 2) // 2)


def worker_count(requested: int | None, device: str, local: bool) -> tuple[int, float]:
    """(workers, GPUs each takes) in the running Ray: as asked (a local Ray was started with that many, or with
    `default_workers`), else one per GPU when the estimator may use CUDA and the cluster has GPUs, else one per two of
    its CPUs. Workers share the GPUs evenly when there are more of them than GPUs."""
    import ray

    resources = ray.cluster_resources()
    gpus = resources.get("GPU", 0) if device != "cpu" else 0
    if local:
        workers = requested or default_workers(device)
    else:
        workers = requested or int(gpus) or max(1, int(resources.get("CPU", 2)) // 2)
    return workers, min(1.0, gpus / workers) if gpus else 0.0


@contextmanager
def ray_session(address: str | None, workers: int) -> Iterator[None]:
    """Ray for the duration of the block: joined at `address` ('auto', or HOST:PORT of a head's GCS), or started
    here with `workers` CPUs."""
    import ray

    try:
        if address is None:
            ray.init(
                address="local", num_cpus=workers, include_dashboard=False, logging_level="ERROR", log_to_driver=False
            )  # "local": a Ray of our own, even beside a running cluster
        else:
            _reachable(address)
            _token_auth()
            ray.init(address=address, logging_level="ERROR", log_to_driver=False)
    except (ConnectionError, RuntimeError, ValueError, ray.exceptions.RayError) as error:
        what = "start Ray" if address is None else f"join the Ray cluster at {address}"
        raise ClusterError(f"cannot {what}: {error}") from None
    try:
        yield
    finally:
        ray.shutdown()


def _reachable(address: str) -> None:
    """A HOST:PORT that accepts no TCP connection within CONNECT_TIMEOUT_S is refused here: Ray's own client would
    retry it for minutes."""
    import socket

    if address == "auto":
        return
    host, _, port = address.rpartition(":")
    if not port.isdigit():
        raise ClusterError(f"cannot join the Ray cluster at {address}: give its head as HOST:PORT, or auto")
    try:
        with socket.create_connection((host or "127.0.0.1", int(port)), timeout=CONNECT_TIMEOUT_S):
            return
    except (OSError, ValueError) as error:
        raise ClusterError(f"cannot join the Ray cluster at {address}: {error}") from None


def _token_auth() -> None:
    """Present the cluster's token when there is one: `ray start` turns token authentication on and keeps the token
    in ~/.ray/auth_token (or RAY_AUTH_TOKEN_PATH, or RAY_AUTH_TOKEN), but a client only sends it with
    RAY_AUTH_MODE=token. A mode the user set stands."""
    if "RAY_AUTH_MODE" in os.environ:
        return
    path = Path(os.environ.get("RAY_AUTH_TOKEN_PATH", Path.home() / ".ray" / "auth_token"))
    if os.environ.get("RAY_AUTH_TOKEN") or path.is_file():
        os.environ["RAY_AUTH_MODE"] = "token"
        from ray._raylet import Config

        Config.initialize("")  # Ray reads its configuration once per process; as Ray's own token setup does


class _Worker:
    """One Ray worker: the estimator built once from the command's options, then one bag or tile per call."""

    def __init__(self, options: dict, threads: int) -> None:
        import torch

        from . import args as checks

        torch.set_num_threads(threads)
        self.options = argparse.Namespace(**options)
        self.estimator = checks.make_estimator(self.options, self.options.radius)

    def pid(self) -> int:
        return os.getpid()

    def bag(self, source: str, target: str) -> tuple[int, str]:
        """`bag` from `source` to `target`; an OUT.partial left by an earlier try of this bag is continued."""
        from ..io.bag_output import partial_path
        from . import bag

        args = argparse.Namespace(**vars(self.options))
        args.input, args.output, args.overwrite = Path(source), Path(target), False
        args.resume = partial_path(args.output).exists()
        args.output.parent.mkdir(parents=True, exist_ok=True)  # OUT_DIR mirrors IN_DIR's folders
        return bag.convert(args, self.estimator)

    def tile(self, points: np.ndarray, query: np.ndarray, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Normals and curvature of a tile's interior (`query` positions), its points named by their global `ids`."""
        return self.estimator.estimate(points, query, point_ids=ids)


@dataclass(frozen=True)
class Pool:
    """The workers of one command."""

    actors: list

    @classmethod
    def start(cls, options: dict, workers: int, gpus_each: float, local: bool) -> Pool:
        """`workers` actors; torch in each gets the cores divided among them: this machine's (a local Ray counts one
        CPU per worker, for scheduling), or the cluster's, each actor reserving its share so that Ray spreads them
        (a fraction of a CPU when there are more workers than CPUs: they still all start)."""
        import ray

        cpus = (os.cpu_count() or 1) if local else int(ray.cluster_resources().get("CPU", workers))
        threads = max(1, cpus // workers)
        reserve = 1 if local else (threads if cpus >= workers else cpus / workers)
        remote = ray.remote(max_restarts=RETRIES, max_task_retries=RETRIES)(_Worker)
        resources = {"num_cpus": reserve, "num_gpus": gpus_each}
        return cls([remote.options(**resources).remote(options, threads) for _ in range(workers)])

    def run(self, jobs: Sequence, submit: Callable, done: Callable, failed: Callable) -> None:
        """Each job to the next free worker (`submit(actor, job)` -> a Ray reference); `done(job, result)` or
        `failed(job, reason)` as each ends. A job that fails, even after Ray's retries, stops no other."""
        import ray

        queue, free, pending = deque(jobs), list(self.actors), {}
        while queue or pending:
            while queue and free:
                job, actor = queue.popleft(), free.pop(0)
                pending[submit(actor, job)] = (job, actor)
            if not pending:  # every worker is gone: the rest cannot run
                for job in queue:
                    failed(job, "no worker left: each died more often than Ray restarts it")
                return
            (ref,), _ = ray.wait(list(pending), num_returns=1)
            job, actor = pending.pop(ref)
            try:
                result = ray.get(ref)
            except ray.exceptions.RayActorError as error:  # the worker is dead for good: it takes no more jobs
                failed(job, _reason(error))
                continue
            except ray.exceptions.RayError as error:
                failed(job, _reason(error))
            else:
                done(job, result)
            free.append(actor)


#: In Ray's out-of-memory message: the machine's memory when the worker was killed, and the threshold it crossed.
_MEMORY_USED = re.compile(r"was ([\d.]+GB used / [\d.]+GB limit)")
_THRESHOLD = re.compile(r"\(([\d.]+)% of \d+B limit\)")


def _reason(error: BaseException) -> str:
    """The worker's own error in one line (Ray wraps it with the remote traceback)."""
    import ray

    if isinstance(error, ray.exceptions.OutOfMemoryError):
        return _out_of_memory(str(error))
    cause = getattr(error, "cause", None)
    text = str(cause) if cause is not None else str(error).strip().splitlines()[-1]
    return " ".join(text.split()) or type(error).__name__


def _out_of_memory(text: str) -> str:
    """Ray's own message is a page of advice and a process table that end in a line which never says what happened:
    that Ray's memory monitor killed the worker, how full the machine was, and which setting moves the line."""
    used, threshold = _MEMORY_USED.search(text), _THRESHOLD.search(text)
    state = f"the machine's memory was {used[1]}" if used else "the machine was low on memory"
    limit = f", over Ray's {threshold[1]} % threshold" if threshold else ""
    return (
        f"Ray's memory monitor killed the worker: {state}{limit} (RAY_memory_usage_threshold); "
        "free memory or run fewer --workers"
    )


def check_workers(workers: int | None, address: str | None) -> None:
    """--workers and --address as given (UsageError, exit 2); whether the address answers is `ray_session`'s."""
    from ..errors import UsageError

    if workers is not None and workers < 1:
        raise UsageError(f"--workers must be an integer >= 1, got {workers}")
    if address is not None and not address.strip():
        raise UsageError("--address must be HOST:PORT or auto")
