"""Data-parallel training on torch.distributed: one clip, N processes (CPU or GPU, one or more nodes).

How a run is split:

* every rank loads the clip and runs the same stage list; stages that are not data-parallel (flow,
  bootstrap, export, evaluation) run on rank 0 only while the others wait at a barrier and then
  read rank 0's cached result (``pipelines/runner.py``);
* training runs on every rank: each draws its own pixels (its own sampler seed) for its share of
  ``train.batch`` (the global batch is the same as in one process), and DDP averages the gradients,
  so all ranks hold the same model; rank 0 alone writes checkpoints, the model and the outputs.

Started either by ``torchrun --nproc_per_node N -m layercam hdr-video ...`` (any torchrun options,
multi-node rendezvous included; the run folder must then be on a file system all nodes share) or by
``layercam hdr-video ... --nproc N``, which starts N local workers through torch's elastic launcher
(the engine behind torchrun), rendezvous on 127.0.0.1. Backend: gloo on CPU, nccl on CUDA.

Outside a torchrun-style environment (no ``WORLD_SIZE`` > 1) every helper here is a no-op, so the
single-process path is unchanged.
"""

from __future__ import annotations

import contextlib
import inspect
import os
import sys
from datetime import timedelta

from layercam.core.errors import LayercamError

# rank 0 may run flow or export for a long clip while the others wait at a barrier
BARRIER_TIMEOUT = timedelta(hours=12)
_SEED_STRIDE = 1_000_003  # rank r samples with seed + r * stride (rank 0: the single-process seed)


def env_world_size() -> int:
    """``WORLD_SIZE`` as set by torchrun / the elastic launcher (1 when absent)."""
    try:
        return int(os.environ.get("WORLD_SIZE", "1"))
    except ValueError:
        return 1


def _dist():
    """``torch.distributed`` when a process group is up, else None."""
    if "torch" not in sys.modules:
        return None
    import torch.distributed as dist

    return dist if dist.is_available() and dist.is_initialized() else None


def rank() -> int:
    d = _dist()
    return d.get_rank() if d else 0


def world_size() -> int:
    d = _dist()
    return d.get_world_size() if d else 1


def is_main() -> bool:
    """True on rank 0 (and in a plain single process): the rank that writes files and reports."""
    return rank() == 0


def barrier() -> None:
    d = _dist()
    if d is None:
        return
    if d.get_backend() == "nccl":
        import torch

        d.barrier(device_ids=[torch.cuda.current_device()])
    else:
        d.barrier()


def rank_seed(seed: int) -> int:
    """This rank's sampler seed: ``seed`` on rank 0, distinct streams on the others."""
    return int(seed) + _SEED_STRIDE * rank()


def rank_batch(batch: int) -> int:
    """This rank's share of the global batch ``batch`` (at least 1 pixel)."""
    n = world_size()
    return max(1, -(-int(batch) // n))


# -- the process group ---------------------------------------------------------------------------
@contextlib.contextmanager
def session(device: str):
    """Joins the process group when started by torchrun (``WORLD_SIZE`` > 1); else does nothing.

    ``device`` is the resolved training device (``"cpu"`` or ``"cuda"``): nccl for CUDA, with this
    process bound to GPU ``LOCAL_RANK``; gloo for the CPU. On a clean exit the group is destroyed
    and the worker ends with ``os._exit(0)``: on these machines a gloo rank sometimes aborts in
    interpreter teardown after ``destroy_process_group()`` (see shared/TOOLING.md), which would
    turn a finished run into a failed one. Errors propagate as usual (non-zero exit).
    """
    if env_world_size() <= 1 or _dist() is not None:
        yield
        return
    import torch
    import torch.distributed as dist

    if str(device).startswith("cuda"):
        if not torch.cuda.is_available():
            raise LayercamError("--device cuda asked for, but torch sees no CUDA device")
        torch.cuda.set_device(int(os.environ.get("LOCAL_RANK", "0")))
        backend = "nccl"
    else:
        backend = "gloo"
    try:
        dist.init_process_group(backend, timeout=BARRIER_TIMEOUT)
    except (RuntimeError, ValueError) as e:
        raise LayercamError(f"cannot join the torch.distributed process group ({backend}): "
                            f"{str(e).splitlines()[0]}") from None
    clean = False
    try:
        yield
        clean = True
    finally:
        with contextlib.suppress(Exception):
            dist.destroy_process_group()
        if clean:
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(0)


class _Losses:
    """Stand-in for ``model.loss_dict`` that goes through DDP (so that gradients are all-reduced)."""

    def __init__(self, ddp):
        self.ddp = ddp

    def __call__(self, batch: dict) -> dict:
        return self.ddp(batch)


def loss_fn(model):
    """``model.loss_dict``, or the same through ``DistributedDataParallel`` inside a process group.

    DDP wraps a small module whose ``forward`` is ``loss_dict``, so the trainer still sees a dict of
    weighted terms and keeps the plain model for checkpoints. ``find_unused_parameters`` because
    which parameters a step touches changes with the schedule (bootstrap, flow decay, blur). If any
    rank's loss is non-finite, every rank gets a non-finite ``other_rank`` term, so all of them skip
    the step together (a rank that skipped backward alone would leave the others waiting in the
    gradient all-reduce).
    """
    d = _dist()
    if d is None or d.get_world_size() == 1:
        return model.loss_dict
    import torch
    from torch import nn
    from torch.nn.parallel import DistributedDataParallel

    class LossModule(nn.Module):
        def __init__(self, m):
            super().__init__()
            self.m = m

        def forward(self, batch):
            terms = self.m.loss_dict(batch)
            total = sum(terms.values()).detach()
            finite = torch.isfinite(total).to(torch.float32).reshape(1)
            d.all_reduce(finite, op=d.ReduceOp.MIN)
            if float(finite) < 1.0 and bool(torch.isfinite(total)):
                terms = {**terms, "other_rank": torch.full((), float("nan"), device=total.device)}
            return terms

    dev = next(model.parameters()).device
    # buffers (h0, exposure table, knots) are constants, the same on every rank: no re-sync per step
    params = inspect.signature(DistributedDataParallel.__init__).parameters
    buffers = {"forward_sync_buffers": False} if "forward_sync_buffers" in params else {"broadcast_buffers": False}
    ddp = DistributedDataParallel(
        LossModule(model),
        device_ids=[dev.index if dev.index is not None else torch.cuda.current_device()]
        if dev.type == "cuda" else None,
        find_unused_parameters=True,
        **buffers,
    )
    return _Losses(ddp)


# -- `--nproc N` (layercam.cli.nproc_args): local workers through torch's elastic launcher --------
def launch_requested(args) -> bool:
    n = getattr(args, "nproc", 1) or 1
    if n < 1:
        raise LayercamError(f"--nproc must be at least 1, got {n}")
    if n > 1 and env_world_size() > 1:
        raise LayercamError("--nproc is for a plain command; under torchrun, leave it out "
                            "(torchrun sets the process count)")
    return n > 1


def _strip_nproc(argv: list[str]) -> list[str]:
    out, skip = [], False
    for a in argv:
        if skip:
            skip = False
        elif a == "--nproc":
            skip = True
        elif not a.startswith("--nproc="):
            out.append(a)
    return out


def launch(args, device: str) -> int:
    """Re-runs this command line (without ``--nproc``) in ``args.nproc`` local workers, like
    ``torchrun --standalone --nproc_per_node N -m layercam ...``. Returns the exit status."""
    import uuid

    import torch

    argv = getattr(args, "_argv", None)
    if argv is None:
        raise LayercamError("--nproc: this entry point did not record its command line")
    n = int(args.nproc)
    if str(device).startswith("cuda") and torch.cuda.device_count() < n:
        raise LayercamError(f"--nproc {n} with --device cuda needs {n} GPUs; torch sees {torch.cuda.device_count()}")
    from torch.distributed.elastic.multiprocessing.errors import ChildFailedError
    from torch.distributed.launcher.api import LaunchConfig, elastic_launch

    # as torchrun does: split the cores between the workers unless the user chose; the workers
    # inherit this environment
    env = {"OMP_NUM_THREADS": str(max(1, (os.cpu_count() or 1) // n))}
    if not str(device).startswith("cuda"):
        env["GLOO_SOCKET_IFNAME"] = "lo"  # local workers talk over loopback only
    saved = {k: os.environ.get(k) for k in env}
    for k, v in env.items():
        os.environ.setdefault(k, v)
    cfg = LaunchConfig(
        min_nodes=1, max_nodes=1, nproc_per_node=n, run_id=uuid.uuid4().hex, rdzv_backend="c10d",
        rdzv_endpoint="127.0.0.1:0", local_addr="127.0.0.1", max_restarts=0, monitor_interval=0.1,
    )
    try:
        elastic_launch(cfg, sys.executable)("-m", "layercam", *_strip_nproc(list(argv)))
    except ChildFailedError as e:
        r, failure = e.get_first_failure()
        code = failure.exitcode if failure.exitcode and failure.exitcode > 0 else 1
        print(f"error: worker rank {r} of {n} failed (exit code {failure.exitcode}); its message "
              "is above", file=sys.stderr)
        return code
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
    return 0
