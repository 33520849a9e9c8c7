"""Spreading work over every JAX device: several GPUs, and several hosts under `jax.distributed`.

Everything here is a no-op on a single device in a single process. Otherwise batched work (the
patch fits of the partition-of-unity method, and model evaluation and gradients called on
concrete points) is split into one share per device: each device works on its own rows, with no
communication, and the results are joined on the host. Evaluation traced inside another
jit-compiled function runs on one device.

Several hosts (`jax.distributed.initialize()`, every process running the same script on the same
input, as JAX's multi-process programs do): the rows are split first between the processes,
then each process splits its part over its own devices (`jax.local_devices()`; a process can
only place arrays on those), and the parts are exchanged with one all-gather
(`jax.experimental.multihost_utils.process_allgather`), after which every process holds the
whole result and goes on identically. So one fit of one input spans every host.

To test on a CPU: `XLA_FLAGS=--xla_force_host_platform_device_count=4` before importing JAX for
several devices; for several processes, `jax.distributed.initialize(coordinator_address,
num_processes, process_id)` in each, with `jax_cpu_collectives_implementation` set to "gloo".
"""

from __future__ import annotations

import jax
import numpy as np


def n_devices() -> int:
    """Shares the work is split into: every device of every process."""
    return jax.local_device_count() * jax.process_count()


def pad_to_devices(size: int) -> int:
    """`size` rounded up to a multiple of the device count."""
    k = n_devices()
    return -(-size // k) * k


def split_over_devices(fn, *arrays):
    """`fn(*arrays)` for a row-wise `fn` (every input and output has the same leading length),
    computed as one contiguous share of the rows per device, then joined on the host (numpy).

    The shares are placed with `jax.device_put` and `fn` (jit-compiled) is dispatched to every
    device before any result is read, so the devices work at the same time; nothing is
    communicated between them within a process, and the processes exchange their parts with one
    all-gather. The rows are padded so that every share has the same shape (one compilation).
    Single device in a single process: `fn(*arrays)`, as numpy.

    (A first version used `shard_map` inside the jit-compiled functions: on simulated CPU devices
    its result resharding deadlocked at random, about one run in three, inside and outside
    lineax's loops; host-level shares need no collective at all.)"""
    n = len(arrays[0])
    procs = jax.process_count()
    if procs == 1:
        return _over_local_devices(fn, arrays, n)
    from jax.experimental import multihost_utils

    # this process's rows, padded so that every process's part has the same shape
    size = -(-n // procs)
    mine = [_rows(x, jax.process_index() * size, size) for x in arrays]
    part = _over_local_devices(fn, mine, size)
    joined = multihost_utils.process_allgather(part, tiled=True)
    return jax.tree.map(lambda a: np.asarray(a)[:n], joined)


def _rows(x, start: int, size: int) -> np.ndarray:
    """Rows start .. start + size of `x`, padded with copies of its first row."""
    part = np.asarray(x[start : start + size])
    if len(part) < size:
        fill = np.broadcast_to(np.asarray(x[:1]), (size - len(part),) + part.shape[1:])
        part = np.concatenate([part, fill]) if len(part) else np.array(fill)
    return part


def _over_local_devices(fn, arrays, n: int):
    """`fn(*arrays)` (leading length n) as one share per local device, joined on the host."""
    k = jax.local_device_count()
    if k == 1:
        return jax.tree.map(np.asarray, fn(*arrays))
    size = -(-n // k)
    outs = [
        fn(*(jax.device_put(_rows(x, i * size, size), dev) for x in arrays))
        for i, dev in enumerate(jax.local_devices())
    ]
    joined = jax.tree.map(lambda *parts: np.concatenate([np.asarray(p) for p in parts]), *outs)
    return jax.tree.map(lambda a: a[:n], joined)
